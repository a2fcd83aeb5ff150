// A transport over bytes in memory, for driving a real Session without sockets (the session
// fuzz target): the client's bytes are given up front and end with a half-close, and what the
// session writes is appended to a string the caller keeps.
#pragma once

#include <cstddef>
#include <memory>
#include <string>

#include "transport.h"

namespace arref::server {

class MemoryTransport final : public Transport {
 public:
  // Each read delivers at most `max_read` bytes, so that frames arrive cut across reads as they
  // do over TCP; after the last byte the session reads end of file.
  MemoryTransport(net::any_io_executor executor, std::string input, std::size_t max_read,
                  std::shared_ptr<std::string> output);

  bool encrypted() const override { return false; }
  net::any_io_executor executor() override { return executor_; }
  std::string peer() override { return "memory"; }

  void AsyncHandshake(DoneHandler done) override;  // there is no TLS: fails
  std::string PeerVerifyError() override { return ""; }
  void AsyncReadSome(net::mutable_buffer buffer, IoHandler done) override;
  void AsyncWrite(net::const_buffer buffer, IoHandler done) override;
  void ShutdownReceive() override { receive_shut_ = true; }
  void AsyncCloseNotify(std::chrono::milliseconds deadline, std::function<void()> done) override;
  void Close() override { closed_ = true; }

 private:
  net::any_io_executor executor_;
  std::string input_;
  std::size_t read_ = 0;  // bytes of input_ delivered
  std::size_t max_read_;
  std::shared_ptr<std::string> output_;
  bool receive_shut_ = false;
  bool closed_ = false;
};

}  // namespace arref::server
