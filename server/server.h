// arref-server: serves robot-to-headset registration over TCP (protocol arref.v1, see
// proto/arref/v1/arref.proto). No Asio or protobuf in this header.
#pragma once

#include <cstdint>
#include <memory>

#include "arref/base/status.h"
#include "server_config.h"

namespace arref::server {

class Server {
 public:
  // Loads the configured robots (fails on any that cannot be loaded).
  static Result<std::unique_ptr<Server>> Create(ServerConfig config);
  ~Server();

  // Binds, prints "listening on ADDRESS:PORT" on stdout, serves until SIGTERM/SIGINT or
  // Stop(), then shuts down gracefully (see README). Returns when everything has stopped.
  Status Run();
  // Thread-safe: starts the same graceful shutdown as SIGTERM.
  void Stop();
  // The bound port (valid once Run has printed the listening line).
  std::uint16_t port() const;

 private:
  struct Impl;
  explicit Server(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace arref::server
