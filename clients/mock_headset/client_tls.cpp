#include "client_tls.h"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>

#include <cerrno>
#include <csignal>
#include <ctime>
#include <mutex>

#include "openssl_errors.h"

namespace arref::headset {
namespace {

using tls::CertificateSubject;
using tls::OpenSslErrorsOrErrno;

bool IsIpAddress(const std::string& host) {
  unsigned char buf[sizeof(in6_addr)];
  return inet_pton(AF_INET, host.c_str(), buf) == 1 || inet_pton(AF_INET6, host.c_str(), buf) == 1;
}

// OpenSSL writes to the socket with write(), which raises SIGPIPE when the server has gone;
// a client must see that as an error, not die of it.
void IgnoreSigpipe() {
  static std::once_flag once;
  std::call_once(once, [] { std::signal(SIGPIPE, SIG_IGN); });
}

Status Unavailable(const std::string& message) { return Status(StatusCode::kUnavailable, message); }

}  // namespace

struct ClientTls::State {
  ~State() {
    if (ssl) SSL_free(ssl);
    if (context) SSL_CTX_free(context);
  }
  SSL_CTX* context = nullptr;
  SSL* ssl = nullptr;
};

namespace {

Status ConfigureContext(SSL_CTX* context, const TlsClientOptions& o) {
  SSL_CTX_set_min_proto_version(context, TLS1_2_VERSION);
  SSL_CTX_set_verify(context, SSL_VERIFY_PEER, nullptr);
  // The server ends a session with close_notify, but cuts a connection it drops (a stalled
  // client) without one; the framing tells a cut stream, so that is an end of stream too.
  SSL_CTX_set_options(context, SSL_OP_IGNORE_UNEXPECTED_EOF);
  const bool loaded = o.ca_file.empty() ? SSL_CTX_set_default_verify_paths(context) == 1
                                        : SSL_CTX_load_verify_locations(context, o.ca_file.c_str(), nullptr) == 1;
  if (!loaded)
    return Status::InvalidArgument(fmt::format("TLS CA {}: cannot be loaded: {}",
                                               o.ca_file.empty() ? "(the system's)" : o.ca_file,
                                               OpenSslErrorsOrErrno()));
  if (o.certificate.empty() != o.private_key.empty())
    return Status::InvalidArgument("a TLS client certificate and its key go together (one is missing)");
  if (!o.certificate.empty()) {
    if (SSL_CTX_use_certificate_chain_file(context, o.certificate.c_str()) != 1)
      return Status::InvalidArgument(
          fmt::format("TLS client certificate {}: {}", o.certificate, OpenSslErrorsOrErrno()));
    if (SSL_CTX_use_PrivateKey_file(context, o.private_key.c_str(), SSL_FILETYPE_PEM) != 1)
      return Status::InvalidArgument(fmt::format("TLS client key {}: {}", o.private_key, OpenSslErrorsOrErrno()));
  }
  return Status::Ok();
}

// The name the certificate must carry: an IP address is matched against its IP entries, a
// host name against its DNS entries (and sent as SNI).
Status ExpectName(SSL* ssl, const std::string& name) {
  if (IsIpAddress(name)) {
    if (X509_VERIFY_PARAM_set1_ip_asc(SSL_get0_param(ssl), name.c_str()) != 1)
      return Status::InvalidArgument("TLS: cannot verify against the address " + name);
    return Status::Ok();
  }
  // SSL_set_tlsext_host_name, without its macro's C-style cast.
  const bool sni = SSL_ctrl(ssl, SSL_CTRL_SET_TLSEXT_HOSTNAME, TLSEXT_NAMETYPE_host_name,
                            const_cast<char*>(name.c_str())) == 1;
  if (SSL_set1_host(ssl, name.c_str()) != 1 || !sni)
    return Status::InvalidArgument("TLS: cannot verify against the host name " + name);
  return Status::Ok();
}

std::string UtcText(const std::tm& t) {
  char text[32];
  return std::strftime(text, sizeof text, "%Y-%m-%d %H:%M:%S UTC", &t) > 0 ? text : "?";
}

std::string UtcText(const ASN1_TIME* time) {
  std::tm t{};
  return ASN1_TIME_to_tm(time, &t) == 1 ? UtcText(t) : "?";
}

// For a certificate refused for its dates: which one the server sent, its validity and this
// machine's clock (a clock set wrong is the usual cause of "not yet valid").
std::string ValidityNote(SSL* ssl) {
  STACK_OF(X509)* chain = SSL_get_peer_cert_chain(ssl);
  for (int i = 0; chain != nullptr && i < sk_X509_num(chain); ++i) {
    X509* c = sk_X509_value(chain, i);
    if (tls::DatesOf(c) == tls::CertificateDates::kValid) continue;
    const std::time_t now = std::time(nullptr);
    std::tm now_utc{};
    gmtime_r(&now, &now_utc);
    return fmt::format("; {} is valid from {} to {}, and this machine's clock says {}", CertificateSubject(c),
                       UtcText(X509_get0_notBefore(c)), UtcText(X509_get0_notAfter(c)), UtcText(now_utc));
  }
  return "";
}

std::string HandshakeFailure(SSL* ssl, const TlsClientOptions& o, const std::string& name) {
  const long verify = SSL_get_verify_result(ssl);
  if (verify == X509_V_OK) return OpenSslErrorsOrErrno();
  const bool dates = verify == X509_V_ERR_CERT_HAS_EXPIRED || verify == X509_V_ERR_CERT_NOT_YET_VALID;
  return fmt::format("the server's certificate did not verify: {} (trusted: {}; expected name: {}{})",
                     X509_verify_cert_error_string(verify), o.ca_file.empty() ? "the system's CAs" : o.ca_file, name,
                     dates ? ValidityNote(ssl) : "");
}

}  // namespace

ClientTls::ClientTls(std::unique_ptr<State> state) : state_(std::move(state)) {}
ClientTls::~ClientTls() = default;

Result<std::unique_ptr<ClientTls>> ClientTls::Handshake(int fd, const std::string& host, const TlsClientOptions& o) {
  IgnoreSigpipe();
  ERR_clear_error();
  auto state = std::make_unique<State>();
  state->context = SSL_CTX_new(TLS_client_method());
  if (!state->context) return Status::Internal("TLS: " + OpenSslErrorsOrErrno());
  ARREF_RETURN_IF_ERROR(ConfigureContext(state->context, o));
  state->ssl = SSL_new(state->context);
  if (!state->ssl || SSL_set_fd(state->ssl, fd) != 1) return Status::Internal("TLS: " + OpenSslErrorsOrErrno());
  const std::string name = o.server_name.empty() ? host : o.server_name;
  ARREF_RETURN_IF_ERROR(ExpectName(state->ssl, name));
  if (SSL_connect(state->ssl) != 1)
    return Unavailable(fmt::format("TLS handshake with {} failed: {}", host, HandshakeFailure(state->ssl, o, name)));
  return std::unique_ptr<ClientTls>(new ClientTls(std::move(state)));
}

Status ClientTls::Write(const char* data, std::size_t size) {
  std::size_t sent = 0;
  while (sent < size) {
    std::size_t n = 0;
    if (SSL_write_ex(state_->ssl, data + sent, size - sent, &n) != 1)
      return Unavailable("sending over TLS: " + OpenSslErrorsOrErrno());
    sent += n;
  }
  return Status::Ok();
}

Result<std::size_t> ClientTls::Read(char* data, std::size_t size) {
  std::size_t n = 0;
  if (SSL_read_ex(state_->ssl, data, size, &n) == 1) return n;
  switch (SSL_get_error(state_->ssl, 0)) {
    case SSL_ERROR_ZERO_RETURN: return std::size_t{0};
    case SSL_ERROR_WANT_READ: return Status::ResourceExhausted("no reply within the socket's timeout");
    case SSL_ERROR_SYSCALL:
      if (errno == EAGAIN || errno == EWOULDBLOCK)
        return Status::ResourceExhausted("no reply within the socket's timeout");
      [[fallthrough]];
    default: return Unavailable("receiving over TLS: " + OpenSslErrorsOrErrno());
  }
}

bool ClientTls::Pending() const { return SSL_pending(state_->ssl) > 0; }

void ClientTls::ShutdownWrite() { SSL_shutdown(state_->ssl); }

}  // namespace arref::headset
