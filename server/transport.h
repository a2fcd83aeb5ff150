// The byte stream under a session: plain TCP, or TLS over it (config section `tls`), so that the
// session's reading, writing and closing stay one path. Only transport.cpp includes Asio's SSL
// headers; the TLS side is reached through the few calls below, their handlers type-erased.
#pragma once

// Boost 1.74 Asio uses std::exchange without including <utility> in C++20 mode.
#include <utility>

#include <boost/asio.hpp>

#include <chrono>
#include <functional>
#include <memory>
#include <string>

#include "arref/base/status.h"
#include "server_config.h"

namespace boost::asio::ssl {
class context;
}

namespace arref::server {

namespace net = boost::asio;
using tcp = net::ip::tcp;

// The server's certificate and key (and the CA clients must be signed by, if any), loaded and
// checked once at startup so that a bad file stops the server with a message naming it.
class TlsContext {
 public:
  static Result<std::unique_ptr<TlsContext>> Load(const TlsConfig& config);
  ~TlsContext();
  net::ssl::context& native() { return *context_; }
  const std::string& description() const { return description_; }  // for the startup log

 private:
  TlsContext() = default;
  std::unique_ptr<net::ssl::context> context_;
  std::string description_;
};

// The byte stream under a session. Sessions see only this interface, so that the same session
// code runs over a socket (MakeSocketTransport) and over bytes in memory (memory_transport.h,
// for the fuzz harness). Every call is made on the session's strand; read, write and handshake
// handlers never run inside the call that starts them.
class Transport {
 public:
  using IoHandler = std::function<void(const boost::system::error_code&, std::size_t)>;
  using DoneHandler = std::function<void(const boost::system::error_code&)>;

  virtual ~Transport() = default;

  virtual bool encrypted() const = 0;
  virtual net::any_io_executor executor() = 0;
  // Who is at the other end, for the logs ("address:port").
  virtual std::string peer() = 0;

  // The server side of the TLS handshake (call only when encrypted).
  virtual void AsyncHandshake(DoneHandler done) = 0;
  // Why the client's certificate was refused (e.g. "certificate has expired"), after a failed
  // handshake; "" when it was not (or there is no TLS).
  virtual std::string PeerVerifyError() = 0;
  virtual void AsyncReadSome(net::mutable_buffer buffer, IoHandler done) = 0;
  virtual void AsyncWrite(net::const_buffer buffer, IoHandler done) = 0;  // the whole buffer
  // Ends a pending read (the client gets no more of our attention); writes may still finish.
  virtual void ShutdownReceive() = 0;
  // Before the Close of a connection the server ends on purpose, with no read or write pending
  // (Asio's SSL stream takes no shutdown beside them; after ShutdownReceive a pending read ends
  // at once): with TLS, sends close_notify, so that the client can tell a finished session from
  // a cut connection. It waits for nothing from the client (TLS does not ask the closer to wait
  // for the peer's close_notify, and the receive side is shut); `deadline` bounds the sending,
  // and at the deadline the socket is closed, so a client that does not read cannot hold the
  // connection. `done` runs then (at once without TLS); the caller then calls Close.
  virtual void AsyncCloseNotify(std::chrono::milliseconds deadline, std::function<void()> done) = 0;
  // At once, without close_notify (a failed or dropped connection): the framing still tells a
  // client that its stream was cut.
  virtual void Close() = 0;

  // The client finished: end of file, or (TLS) the connection closed without close_notify.
  static bool IsEndOfStream(const boost::system::error_code& ec);
};

// A TCP connection; tls == nullptr: plain, else TLS over it (the server's certificate).
std::unique_ptr<Transport> MakeSocketTransport(tcp::socket socket, TlsContext* tls);

}  // namespace arref::server
