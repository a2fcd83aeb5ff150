#include "transport.h"

#include <fmt/format.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include <boost/asio/ssl.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "openssl_errors.h"

namespace arref::server {
namespace {

namespace ssl = net::ssl;

using tls::CertificateSubject;
using tls::OpenSslErrors;

Status CheckReadable(const std::string& path, const std::string& key) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return Status::NotFound(fmt::format("{} {}: no such file", key, path));
  if (!std::ifstream(path)) return Status::IoError(fmt::format("{} {}: cannot be read (permissions?)", key, path));
  return Status::Ok();
}

// A passphrase callback that answers nothing: without it OpenSSL would prompt on the terminal
// of a daemon for an encrypted key.
int NoPassphrase(char*, int, int, void*) { return 0; }

struct PkeyDeleter {
  void operator()(EVP_PKEY* k) const { EVP_PKEY_free(k); }
};
using Pkey = std::unique_ptr<EVP_PKEY, PkeyDeleter>;

Result<Pkey> ReadPrivateKey(const std::string& path) {
  ARREF_RETURN_IF_ERROR(CheckReadable(path, "tls.private_key"));
  std::unique_ptr<FILE, int (*)(FILE*)> file(std::fopen(path.c_str(), "r"), &std::fclose);
  if (!file) return Status::IoError(fmt::format("tls.private_key {}: cannot be opened", path));
  Pkey key(PEM_read_PrivateKey(file.get(), nullptr, &NoPassphrase, nullptr));
  if (!key)
    return Status::InvalidArgument(fmt::format(
        "tls.private_key {}: not an unencrypted PEM private key (an encrypted key can be decrypted with `openssl pkey "
        "-in KEY -out KEY.plain`): {}", path, OpenSslErrors()));
  return key;
}

Status UseCertificateAndKey(ssl::context& context, const TlsConfig& config) {
  ARREF_RETURN_IF_ERROR(CheckReadable(config.certificate_chain, "tls.certificate_chain"));
  ARREF_ASSIGN_OR_RETURN(Pkey key, ReadPrivateKey(config.private_key));
  SSL_CTX* native = context.native_handle();
  if (SSL_CTX_use_certificate_chain_file(native, config.certificate_chain.c_str()) != 1)
    return Status::InvalidArgument(fmt::format("tls.certificate_chain {}: not a PEM certificate chain: {}",
                                               config.certificate_chain, OpenSslErrors()));
  if (X509_check_private_key(SSL_CTX_get0_certificate(native), key.get()) != 1) {
    OpenSslErrors();
    return Status::InvalidArgument(fmt::format("tls.private_key {} does not match the certificate in "
                                               "tls.certificate_chain {} (the key of another certificate?)",
                                               config.private_key, config.certificate_chain));
  }
  if (SSL_CTX_use_PrivateKey(native, key.get()) != 1)
    return Status::InvalidArgument(
        fmt::format("tls.private_key {}: OpenSSL refused it: {}", config.private_key, OpenSslErrors()));
  return Status::Ok();
}

// Mutual TLS: only clients holding a certificate that client_ca signed complete the handshake.
Status RequireClientCertificates(ssl::context& context, const std::string& client_ca) {
  ARREF_RETURN_IF_ERROR(CheckReadable(client_ca, "tls.client_ca"));
  boost::system::error_code ec;
  context.load_verify_file(client_ca, ec);
  if (ec)
    return Status::InvalidArgument(
        fmt::format("tls.client_ca {}: not a PEM CA certificate: {}", client_ca, ec.message()));
  context.set_verify_mode(ssl::verify_peer | ssl::verify_fail_if_no_peer_cert);
  return Status::Ok();
}

// Clients refuse a certificate outside its validity: said at startup rather than only in
// each client's error.
std::string ValidityWarning(const X509* certificate) {
  switch (tls::DatesOf(certificate)) {
    case tls::CertificateDates::kExpired: return "; the certificate HAS EXPIRED: clients will refuse it";
    case tls::CertificateDates::kNotYetValid:
      return "; the certificate is NOT YET VALID (or this machine's clock is wrong): clients will refuse it";
    case tls::CertificateDates::kValid: break;
  }
  return "";
}

}  // namespace

// ---------------------------------------------------------------- TlsContext

Result<std::unique_ptr<TlsContext>> TlsContext::Load(const TlsConfig& config) {
  ERR_clear_error();
  std::unique_ptr<TlsContext> out(new TlsContext());
  out->context_ = std::make_unique<ssl::context>(ssl::context::tls_server);
  ssl::context& context = *out->context_;
  context.set_options(ssl::context::default_workarounds | ssl::context::no_sslv2 | ssl::context::no_sslv3 |
                      ssl::context::no_tlsv1 | ssl::context::no_tlsv1_1 | ssl::context::single_dh_use);
  SSL_CTX_set_default_passwd_cb(context.native_handle(), &NoPassphrase);
  ARREF_RETURN_IF_ERROR(UseCertificateAndKey(context, config));
  if (!config.client_ca.empty()) ARREF_RETURN_IF_ERROR(RequireClientCertificates(context, config.client_ca));
  X509* certificate = SSL_CTX_get0_certificate(context.native_handle());
  out->description_ = fmt::format("TLS 1.2+ with {} ({}){}{}", config.certificate_chain,
                                  CertificateSubject(certificate), ValidityWarning(certificate),
                                  config.client_ca.empty() ? "" : "; client certificates signed by " + config.client_ca);
  return out;
}

TlsContext::~TlsContext() = default;

// ---------------------------------------------------------------- SocketTransport

namespace {

class SocketTransport final : public Transport {
 public:
  // The TLS layer refers to socket_, so a SocketTransport stays in place (held by pointer).
  SocketTransport(tcp::socket socket, TlsContext* tls) : socket_(std::move(socket)) {
    if (tls) tls_ = std::make_unique<Tls>(socket_, tls->native());
  }

  bool encrypted() const override { return tls_ != nullptr; }
  net::any_io_executor executor() override { return socket_.get_executor(); }

  std::string peer() override {
    boost::system::error_code ec;
    const auto endpoint = socket_.remote_endpoint(ec);
    return ec ? "?" : endpoint.address().to_string() + ":" + std::to_string(endpoint.port());
  }

  void AsyncHandshake(DoneHandler done) override {
    tls_->stream.async_handshake(ssl::stream_base::server, std::move(done));
  }

  std::string PeerVerifyError() override {
    if (!tls_) return "";
    const long verify = SSL_get_verify_result(tls_->stream.native_handle());
    return verify == X509_V_OK ? "" : X509_verify_cert_error_string(verify);
  }

  void AsyncReadSome(net::mutable_buffer buffer, IoHandler done) override {
    if (tls_)
      tls_->stream.async_read_some(buffer, std::move(done));
    else
      socket_.async_read_some(buffer, std::move(done));
  }

  void AsyncWrite(net::const_buffer buffer, IoHandler done) override {
    if (tls_)
      net::async_write(tls_->stream, buffer, std::move(done));
    else
      net::async_write(socket_, buffer, std::move(done));
  }

  void ShutdownReceive() override {
    boost::system::error_code ignored;
    socket_.shutdown(tcp::socket::shutdown_receive, ignored);
  }

  void AsyncCloseNotify(std::chrono::milliseconds deadline, std::function<void()> done) override;

  void Close() override {
    boost::system::error_code ignored;
    socket_.shutdown(tcp::socket::shutdown_both, ignored);
    socket_.close(ignored);
  }

 private:
  struct Tls {
    Tls(tcp::socket& socket, ssl::context& context) : stream(socket, context), shutdown_timer(socket.get_executor()) {}
    ssl::stream<tcp::socket&> stream;
    net::steady_timer shutdown_timer;
  };
  tcp::socket socket_;
  std::unique_ptr<Tls> tls_;
};

void SocketTransport::AsyncCloseNotify(std::chrono::milliseconds deadline, std::function<void()> done) {
  if (!tls_) return done();
  // At the deadline, Close, which ends the shutdown with an error. Both handlers share `done`
  // (and what it holds, the session): neither outlives it.
  auto finish = std::make_shared<std::function<void()>>(std::move(done));
  tls_->shutdown_timer.expires_after(deadline);
  tls_->shutdown_timer.async_wait([this, finish](const boost::system::error_code& ec) {
    if (!ec) Close();
  });
  tls_->stream.async_shutdown([this, finish](const boost::system::error_code&) {
    // An error is the client's (gone, or it cut its side) or the deadline's: nothing more to send.
    tls_->shutdown_timer.cancel();
    (*finish)();
  });
}

}  // namespace

std::unique_ptr<Transport> MakeSocketTransport(tcp::socket socket, TlsContext* tls) {
  return std::make_unique<SocketTransport>(std::move(socket), tls);
}

bool Transport::IsEndOfStream(const boost::system::error_code& ec) {
  return ec == net::error::eof || ec == ssl::error::stream_truncated;
}

}  // namespace arref::server
