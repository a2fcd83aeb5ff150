// TLS over a connected blocking socket, as a headset app would use it: the server's
// certificate is verified against a CA (a file, or the system's) and must name the host the
// client connected to. OpenSSL stays inside client_tls.cpp.
#pragma once

#include <cstddef>
#include <memory>
#include <string>

#include "arref/base/status.h"

namespace arref::headset {

struct TlsClientOptions {
  bool enabled = false;
  std::string ca_file;      // PEM CA that signed the server's certificate; empty: the system's CAs
  std::string server_name;  // the name the certificate must carry; empty: the host connected to
  // A certificate of our own, for a server that requires one (its tls.client_ca); PEM files.
  std::string certificate;
  std::string private_key;
};

class ClientTls {
 public:
  // The handshake on `fd` (connected, blocking, its receive timeout set); kUnavailable with the
  // reason (the verification error, naming the CA) when it fails.
  static Result<std::unique_ptr<ClientTls>> Handshake(int fd, const std::string& host, const TlsClientOptions& options);
  ~ClientTls();
  ClientTls(const ClientTls&) = delete;
  ClientTls& operator=(const ClientTls&) = delete;

  Status Write(const char* data, std::size_t size);
  // Bytes read (> 0); 0: the server closed the connection; kResourceExhausted: the socket's
  // receive timeout passed.
  Result<std::size_t> Read(char* data, std::size_t size);
  // Decrypted bytes already here, which poll() on the socket would not announce.
  bool Pending() const;
  // close_notify: the server sees the end of our stream and can still answer.
  void ShutdownWrite();

 private:
  struct State;
  explicit ClientTls(std::unique_ptr<State> state);
  std::unique_ptr<State> state_;
};

}  // namespace arref::headset
