// TLS end to end: the real arref-server process on loopback with a certificate from a throwaway
// CA made here by Debian's openssl command line, and the mock headset's client library (and
// executable) verifying it.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <openssl/ssl.h>
#include <poll.h>
#include <fcntl.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "headset_client.h"
#include "openssl_errors.h"
#include "server_process.h"
#include "test_support.h"
#include "transport.h"

namespace arref::headset {
namespace {

using arref::testing::RunCommand;
using arref::testing::ScopedTempDir;
using arref::testing::ServerProcess;
using arref::testing::ServerSettings;
using Clock = std::chrono::steady_clock;
namespace net = boost::asio;
using tcp = net::ip::tcp;

const std::string kMockPath = ARREF_BINARY_DIR "/clients/mock_headset/arref-mock-headset";
constexpr double kReplyTimeout = 120.0;  // only to avoid hanging

void Run(const std::string& command) {
  const auto r = RunCommand(command);
  ASSERT_EQ(r.exit_code, 0) << command << "\n" << r.err;
}

// A CA and a certificate it signed for localhost and 127.0.0.1 (P-256 keys: fast to make).
struct Pki {
  std::string ca, server_cert, server_key;
  std::string client_cert, client_key;  // for a server with tls.client_ca
  std::string prefix;                   // of the CA's other files (key, extensions, openssl ca's database)
};

const std::string kEcKey = " -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes ";

// `openssl ca` (unlike `openssl x509 -req`) sets any validity dates; it keeps a database of
// what it signed, allowed to hold the same subject twice.
void WriteCaDatabase(const std::string& d) {
  std::ofstream(d + "_ca.cnf") << "[ca]\ndefault_ca = test\n[test]\ndatabase = " << d << "_ca_index.txt\n"
                               << "new_certs_dir = " << std::filesystem::path(d).parent_path().string() << "\n"
                               << "serial = " << d << "_ca_serial\ndefault_md = sha256\npolicy = any\n"
                               << "unique_subject = no\n[any]\ncommonName = supplied\n";
  std::ofstream(d + "_ca_index.txt");
  std::ofstream(d + "_ca_serial") << "1000\n";
}

Pki MakePki(const std::string& dir, const std::string& name) {
  const std::string d = dir + "/" + name;
  const std::string& ec = kEcKey;
  Pki p{d + "_ca.pem", d + "_server.pem", d + "_server.key", d + "_client.pem", d + "_client.key", d};
  std::ofstream(d + "_ext.cnf") << "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
                                   "extendedKeyUsage=serverAuth\n";
  std::ofstream(d + "_client_ext.cnf") << "basicConstraints=CA:FALSE\nextendedKeyUsage=clientAuth\n";
  WriteCaDatabase(d);
  Run("openssl req -x509" + ec + "-keyout " + d + "_ca.key -out " + p.ca + " -days 2 -subj '/CN=arref test CA " + name +
      "'");
  Run("openssl req" + ec + "-keyout " + p.server_key + " -out " + d + "_server.csr -subj /CN=localhost");
  Run("openssl x509 -req -in " + d + "_server.csr -CA " + p.ca + " -CAkey " + d + "_ca.key -CAcreateserial -out " +
      p.server_cert + " -days 2 -extfile " + d + "_ext.cnf");
  Run("openssl req" + ec + "-keyout " + p.client_key + " -out " + d + "_client.csr -subj /CN=headset-1");
  Run("openssl x509 -req -in " + d + "_client.csr -CA " + p.ca + " -CAkey " + d + "_ca.key -CAcreateserial -out " +
      p.client_cert + " -days 2 -extfile " + d + "_client_ext.cnf");
  return p;
}

// Validity dates as `openssl ca` takes them: long past, and far ahead.
struct Dates {
  std::string start, end;
};
const Dates kExpired{"20200101000000Z", "20200102000000Z"};
const Dates kNotYetValid{"20990101000000Z", "20991231000000Z"};

struct Issued {
  std::string cert, key;
};

// A certificate from pki's CA valid only within `dates`: the server's (localhost, 127.0.0.1)
// or, `client`, a headset's.
Issued IssueWithDates(const Pki& pki, const std::string& name, bool client, const Dates& dates) {
  const std::string d = pki.prefix + "_" + name;
  Run("openssl req" + kEcKey + "-keyout " + d + ".key -out " + d + ".csr -subj /CN=" +
      (client ? "headset-1" : "localhost"));
  Run("openssl ca -batch -notext -config " + pki.prefix + "_ca.cnf -cert " + pki.ca + " -keyfile " + pki.prefix +
      "_ca.key -in " + d + ".csr -out " + d + ".pem -startdate " + dates.start + " -enddate " + dates.end +
      " -extfile " + pki.prefix + (client ? "_client_ext.cnf" : "_ext.cnf"));
  return {d + ".pem", d + ".key"};
}

std::string TlsYaml(const std::string& cert, const std::string& key) {
  return "tls:\n  certificate_chain: " + cert + "\n  private_key: " + key + "\n";
}

class Tls : public ::testing::Test {
 protected:
  void SetUp() override {
    pki_ = MakePki(dir_.path(), "good");
    other_ = MakePki(dir_.path(), "other");
  }

  ServerSettings Settings() const {
    ServerSettings s;
    s.sections_yaml = TlsYaml(pki_.server_cert, pki_.server_key);
    return s;
  }

  TlsClientOptions Trusting(const std::string& ca) const { return {.enabled = true, .ca_file = ca}; }

  // Hello -> HelloReply over a fresh TLS connection (by default trusting our CA).
  void ExpectHelloWorks(const ServerProcess& server) const { ExpectHelloWorks(server, Trusting(pki_.ca)); }
  void ExpectHelloWorks(const ServerProcess& server, const TlsClientOptions& tls) const {
    auto conn = Connection::Connect("127.0.0.1", server.port(), 10, 0, tls);
    ASSERT_TRUE(conn.ok()) << conn.status().ToString() << "\n" << server.Log();
    ASSERT_TRUE(conn->Send(Hello()).ok());
    auto reply = conn->Receive(kReplyTimeout);
    ASSERT_TRUE(reply.ok()) << reply.status().ToString();
    EXPECT_TRUE(reply->has_hello_reply());
  }
  static pb::ClientMessage Hello() {
    pb::ClientMessage m;
    m.mutable_hello()->set_protocol_version(wire::kProtocolVersion);
    m.mutable_hello()->set_client_name("tls-test");
    return m;
  }

  ScopedTempDir dir_;
  Pki pki_, other_;
};

TEST_F(Tls, MockHeadsetRegistersOverTls) {
  ServerProcess server(Settings());
  auto scene = SimulatedScene(1);
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  HeadsetOptions o;
  o.host = "127.0.0.1";
  o.port = server.port();
  o.timeout_s = kReplyTimeout;
  o.batch_interval_s = 0.01;
  o.tls = Trusting(pki_.ca);
  const HeadsetRun run = RunHeadset(*scene, o);
  ASSERT_TRUE(run.status.ok()) << run.status.ToString() << "\n" << server.Log();
  ASSERT_EQ(run.registrations.size(), 1u);
  const auto status = run.registrations[0].result.status();
  EXPECT_TRUE(status == pb::RESULT_STATUS_OK || status == pb::RESULT_STATUS_LOW_CONFIDENCE) << pb::ResultStatus_Name(status);
  EXPECT_NE(server.Log().find("(TLS)"), std::string::npos);
}

TEST_F(Tls, TheMockHeadsetVerifiesTheHostName) {
  ServerProcess server(Settings());
  const std::string base = kMockPath + " --port " + std::to_string(server.port()) + " --tls-ca " + pki_.ca +
                           " --batches 1 --timeout 60 --rng-seed 1";
  // "localhost" is in the certificate; the test cell's registration is not needed to see that.
  const auto wrong_name = RunCommand(base + " --host 127.0.0.1 --tls-server-name arref.example");
  EXPECT_NE(wrong_name.exit_code, 0);
  EXPECT_NE(wrong_name.out.find("did not verify"), std::string::npos) << wrong_name.out << wrong_name.err;
  EXPECT_NE(wrong_name.out.find("hostname mismatch"), std::string::npos) << wrong_name.out;
  const auto wrong_ca = RunCommand(kMockPath + " --port " + std::to_string(server.port()) + " --tls-ca " + other_.ca);
  EXPECT_NE(wrong_ca.exit_code, 0);
  EXPECT_NE(wrong_ca.out.find("unable to get local issuer certificate"), std::string::npos) << wrong_ca.out;
  EXPECT_TRUE(server.alive());
  ExpectHelloWorks(server);
}

TEST_F(Tls, AClientTrustingAnotherCaFailsAndTheServerKeepsServing) {
  ServerProcess server(Settings());
  auto conn = Connection::Connect("127.0.0.1", server.port(), 10, 0, Trusting(other_.ca));
  ASSERT_FALSE(conn.ok());
  const std::string message = conn.status().message();
  EXPECT_NE(message.find("the server's certificate did not verify"), std::string::npos) << message;
  EXPECT_NE(message.find(other_.ca), std::string::npos) << message;  // names what it trusted
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  EXPECT_NE(server.Log().find("TLS handshake failed"), std::string::npos) << server.Log();
  EXPECT_TRUE(server.alive());
  ExpectHelloWorks(server);
}

// True once the server's log holds `text` (it is written as the server goes), false after timeout_s.
bool LogShows(const ServerProcess& server, const std::string& text, double timeout_s = 10) {
  const auto deadline = Clock::now() + std::chrono::duration<double>(timeout_s);
  while (server.Log().find(text) == std::string::npos) {
    if (Clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return true;
}

// A server certificate outside its dates: the server warns at startup, and the client refuses
// it with the reason, the certificate's dates and its own clock (a wrong clock is the usual
// cause of "not yet valid"); the server keeps serving.
TEST_F(Tls, AClientRefusesAServerCertificateOutsideItsDatesSayingWhy) {
  struct Case {
    std::string name;
    Dates dates;
    std::string reason, shown_dates, startup_warning;
  };
  const std::vector<Case> cases{
      {"expired", kExpired, "certificate has expired", "valid from 2020-01-01 00:00:00 UTC to 2020-01-02 00:00:00 UTC",
       "the certificate HAS EXPIRED"},
      {"not_yet_valid", kNotYetValid, "certificate is not yet valid",
       "valid from 2099-01-01 00:00:00 UTC to 2099-12-31 00:00:00 UTC", "the certificate is NOT YET VALID"}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Issued issued = IssueWithDates(pki_, c.name, false, c.dates);
    ServerSettings s;
    s.sections_yaml = TlsYaml(issued.cert, issued.key);
    ServerProcess server(s);
    EXPECT_TRUE(LogShows(server, c.startup_warning)) << server.Log();
    auto conn = Connection::Connect("127.0.0.1", server.port(), 10, 0, Trusting(pki_.ca));
    ASSERT_FALSE(conn.ok()) << "connected to a server whose certificate is " << c.name;
    const std::string message = conn.status().message();
    EXPECT_NE(message.find("the server's certificate did not verify: " + c.reason), std::string::npos) << message;
    EXPECT_NE(message.find("/CN=localhost is " + c.shown_dates), std::string::npos) << message;
    EXPECT_NE(message.find("this machine's clock says 20"), std::string::npos) << message;
    EXPECT_TRUE(LogShows(server, "TLS handshake failed")) << server.Log();
    EXPECT_TRUE(server.alive());
  }
}

// The mock headset's command line says it as well, and fails.
TEST_F(Tls, TheMockHeadsetRefusesAnExpiredServerCertificate) {
  const Issued expired = IssueWithDates(pki_, "expired", false, kExpired);
  ServerSettings s;
  s.sections_yaml = TlsYaml(expired.cert, expired.key);
  ServerProcess server(s);
  const auto run = RunCommand(kMockPath + " --port " + std::to_string(server.port()) + " --tls-ca " + pki_.ca +
                              " --batches 1 --timeout 60 --rng-seed 1");
  EXPECT_NE(run.exit_code, 0);
  EXPECT_NE(run.out.find("did not verify: certificate has expired"), std::string::npos) << run.out << run.err;
}

// tls.client_ca: a client certificate its CA signed but expired is refused, the server's log
// says why, and the server goes on serving headsets with valid certificates.
TEST_F(Tls, AnExpiredClientCertificateIsRefusedAndTheServerKeepsServing) {
  ServerSettings s = Settings();
  s.sections_yaml += "  client_ca: " + pki_.ca + "\n";
  ServerProcess server(s);
  const Issued expired = IssueWithDates(pki_, "expired_client", true, kExpired);
  TlsClientOptions o = Trusting(pki_.ca);
  o.certificate = expired.cert;
  o.private_key = expired.key;
  // TLS 1.3: the client's side of the handshake ends before the server checks the certificate,
  // so the server's alert shows at the connect or at the first read.
  std::string refusal;
  auto conn = Connection::Connect("127.0.0.1", server.port(), 10, 0, o);
  if (conn.ok()) {
    (void)conn->Send(Hello());
    const auto reply = conn->Receive(30);
    ASSERT_FALSE(reply.ok()) << "an expired client certificate was let in";
    refusal = reply.status().message();
  } else {
    refusal = conn.status().message();
  }
  EXPECT_NE(refusal.find("certificate expired"), std::string::npos) << refusal;  // the server's alert
  EXPECT_TRUE(LogShows(server, "(the client's certificate: certificate has expired)")) << server.Log();
  EXPECT_TRUE(server.alive());
  TlsClientOptions valid = Trusting(pki_.ca);
  valid.certificate = pki_.client_cert;
  valid.private_key = pki_.client_key;
  ExpectHelloWorks(server, valid);
}

TEST_F(Tls, APlaintextClientIsClosedAndTheServerKeepsServing) {
  ServerProcess server(Settings());
  auto plain = Connection::Connect("127.0.0.1", server.port(), 10);
  ASSERT_TRUE(plain.ok());
  pb::ClientMessage m;
  m.mutable_hello()->set_protocol_version(wire::kProtocolVersion);
  ASSERT_TRUE(plain->Send(m).ok());
  const auto reply = plain->Receive(30);
  ASSERT_FALSE(reply.ok());
  EXPECT_EQ(reply.status().code(), StatusCode::kUnavailable) << reply.status().ToString();  // closed, not timed out
  EXPECT_TRUE(server.alive());
  ExpectHelloWorks(server);
}

// Opens a TCP connection that never starts (or never finishes) the TLS handshake.
int StalledConnection(std::uint16_t port, bool partial_client_hello) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(port);
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  EXPECT_EQ(connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  if (partial_client_hello) {
    EXPECT_EQ(send(fd, "\x16\x03\x01\x02\x00", 5, MSG_NOSIGNAL), 5);  // a record header only
  }
  return fd;
}

// Seconds until the server closes fd (reads return 0 or an error), or -1 after timeout_s.
double SecondsUntilClosed(int fd, double timeout_s) {
  const auto start = Clock::now();
  while (std::chrono::duration<double>(Clock::now() - start).count() < timeout_s) {
    pollfd p{fd, POLLIN, 0};
    if (poll(&p, 1, 100) <= 0) continue;
    char buf[256];
    if (recv(fd, buf, sizeof buf, 0) <= 0) return std::chrono::duration<double>(Clock::now() - start).count();
  }
  return -1;
}

TEST_F(Tls, AStalledHandshakeIsClosedByTheHelloDeadline) {
  ServerSettings s = Settings();
  s.server_yaml = "  hello_timeout_s: 1\n";
  ServerProcess server(s);
  const int silent = StalledConnection(server.port(), false);
  const int partial = StalledConnection(server.port(), true);
  const double silent_s = SecondsUntilClosed(silent, 20);
  const double partial_s = SecondsUntilClosed(partial, 20);
  EXPECT_GE(silent_s, 0.5);
  EXPECT_LT(silent_s, 10) << "never closed";
  EXPECT_GE(partial_s, 0);
  EXPECT_LT(partial_s, 10) << "never closed";
  close(silent);
  close(partial);
  EXPECT_NE(server.Log().find("no completed TLS handshake within 1 s of connecting (server.hello_timeout_s)"),
            std::string::npos) << server.Log();
  ExpectHelloWorks(server);
}

// A connection still in its handshake is a connection owing Hello: when they fill
// limits.max_pending_connections the oldest goes, and a headset still gets in.
TEST_F(Tls, StalledHandshakesCountAsPendingAndCannotLockHeadsetsOut) {
  ServerSettings s = Settings();
  s.limits_yaml = "  max_pending_connections: 2\n";
  ServerProcess server(s);
  std::vector<int> stalled;
  for (int i = 0; i < 3; ++i) stalled.push_back(StalledConnection(server.port(), true));
  const double first_s = SecondsUntilClosed(stalled[0], 3);  // evicted long before the 5 s deadline
  EXPECT_GE(first_s, 0) << server.Log();
  ExpectHelloWorks(server);
  for (int fd : stalled) close(fd);
}

// ---------------------------------------------------------------- close_notify

// A TLS client on OpenSSL itself, strict where the mock headset is lenient (that takes a cut
// connection as an end of stream too): it tells the server's close_notify from a cut stream.
class StrictTlsClient {
 public:
  StrictTlsClient(std::uint16_t port, const std::string& ca) : fd_(StalledConnection(port, false)) {
    context_ = SSL_CTX_new(TLS_client_method());
    SSL_CTX_set_verify(context_, SSL_VERIFY_PEER, nullptr);
    if (SSL_CTX_load_verify_locations(context_, ca.c_str(), nullptr) != 1) ended_ = "CA: " + tls::OpenSslErrors();
    ssl_ = SSL_new(context_);
    SSL_set_fd(ssl_, fd_);
    const timeval timeout{30, 0};  // bounds every read below
    setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
    if (ended_.empty() && SSL_connect(ssl_) != 1) ended_ = "handshake: " + tls::OpenSslErrors();
  }
  ~StrictTlsClient() {
    SSL_free(ssl_);
    SSL_CTX_free(context_);
    close(fd_);
  }
  StrictTlsClient(const StrictTlsClient&) = delete;
  StrictTlsClient& operator=(const StrictTlsClient&) = delete;

  bool connected() const { return ended_.empty(); }
  int fd() const { return fd_; }
  // How the stream ended: "close_notify", "cut: <OpenSSL's error>", "timeout", ... ("" while open).
  const std::string& ended() const { return ended_; }

  bool Send(const pb::ClientMessage& message) {
    const std::string frame = wire::EncodeFrame(message);
    std::size_t n = 0;
    return SSL_write_ex(ssl_, frame.data(), frame.size(), &n) == 1 && n == frame.size();
  }

  // The next message, or nullopt once the stream has ended (ended() says how).
  std::optional<pb::ServerMessage> Next() {
    while (ended_.empty()) {
      if (auto message = TakeFrame()) return message;
      char buf[16384];
      std::size_t n = 0;
      if (SSL_read_ex(ssl_, buf, sizeof buf, &n) == 1) {
        rx_.append(buf, n);
        continue;
      }
      ended_ = HowItEnded(SSL_get_error(ssl_, 0));
    }
    return std::nullopt;
  }

  // Every message until the end of the stream.
  std::vector<pb::ServerMessage> ReadToEnd() {
    std::vector<pb::ServerMessage> out;
    while (auto message = Next()) out.push_back(*message);
    return out;
  }

 private:
  std::optional<pb::ServerMessage> TakeFrame() {
    const auto* data = reinterpret_cast<const std::uint8_t*>(rx_.data());
    const auto h = wire::DecodeFrameHeader(data, rx_.size(), 64u << 20);
    if (h.state != wire::FrameHeader::State::kComplete || rx_.size() < h.header_bytes + h.body_bytes)
      return std::nullopt;
    pb::ServerMessage message;
    EXPECT_TRUE(message.ParseFromArray(data + h.header_bytes, static_cast<int>(h.body_bytes)));
    rx_.erase(0, h.header_bytes + h.body_bytes);
    return message;
  }

  std::string HowItEnded(int error) {
    const int system_error = errno;
    if (error == SSL_ERROR_ZERO_RETURN) return "close_notify";
    if (error == SSL_ERROR_WANT_READ || (error == SSL_ERROR_SYSCALL && system_error == EAGAIN)) return "timeout";
    const std::string queued = tls::OpenSslErrors();  // "unexpected eof while reading": cut
    return "cut: " + (queued.empty() ? std::string(std::strerror(system_error)) : queued);
  }

  int fd_;
  SSL_CTX* context_ = nullptr;
  SSL* ssl_ = nullptr;
  std::string ended_;
  std::string rx_;
};

// The server ends a session (a fatal error; the idle timeout) with TLS close_notify: a strict
// client reads the last Error, then a clean end of stream (SSL_ERROR_ZERO_RETURN), not a cut.
TEST_F(Tls, TheServerEndsASessionWithCloseNotify) {
  ServerSettings s = Settings();
  s.idle_timeout_s = 1;
  ServerProcess server(s);
  {
    SCOPED_TRACE("a fatal error: Ping before Hello");
    StrictTlsClient client(server.port(), pki_.ca);
    ASSERT_TRUE(client.connected()) << client.ended();
    pb::ClientMessage ping;
    ping.mutable_ping()->set_nonce(1);
    ASSERT_TRUE(client.Send(ping));
    const auto messages = client.ReadToEnd();
    EXPECT_EQ(client.ended(), "close_notify");
    ASSERT_EQ(messages.size(), 1u);
    EXPECT_EQ(messages[0].error().code(), pb::ERROR_CODE_NOT_READY);
  }
  {
    SCOPED_TRACE("the idle timeout");
    StrictTlsClient client(server.port(), pki_.ca);
    ASSERT_TRUE(client.connected()) << client.ended();
    ASSERT_TRUE(client.Send(Hello()));
    const auto messages = client.ReadToEnd();
    EXPECT_EQ(client.ended(), "close_notify");
    ASSERT_EQ(messages.size(), 2u);
    EXPECT_TRUE(messages[0].has_hello_reply());
    EXPECT_EQ(messages[1].error().code(), pb::ERROR_CODE_IDLE_TIMEOUT);
  }
  EXPECT_TRUE(server.alive());
}

// SIGTERM: every session gets ServerShutdown, then close_notify, and the server exits 0.
TEST_F(Tls, AServerShuttingDownEndsSessionsWithCloseNotify) {
  ServerProcess server(Settings());
  StrictTlsClient client(server.port(), pki_.ca);
  ASSERT_TRUE(client.connected()) << client.ended();
  ASSERT_TRUE(client.Send(Hello()));
  const auto reply = client.Next();  // the session is ready before the signal
  ASSERT_TRUE(reply && reply->has_hello_reply()) << client.ended();
  EXPECT_EQ(server.SignalAndWait(SIGTERM, 60), 0);
  const auto messages = client.ReadToEnd();  // what the server sent before it exited
  EXPECT_EQ(client.ended(), "close_notify");
  ASSERT_FALSE(messages.empty());
  EXPECT_TRUE(messages.back().has_shutdown());
}

// A client that neither reads nor answers once the server ends its session does not hold the
// connection: the server closes it within the idle timeout and the close_notify deadline
// (2 s) without it, and serves others.
TEST_F(Tls, AClientThatNeverAnswersTheCloseIsClosedWithinTheDeadline) {
  ServerSettings s = Settings();
  s.idle_timeout_s = 1;
  ServerProcess server(s);
  StrictTlsClient client(server.port(), pki_.ca);
  ASSERT_TRUE(client.connected()) << client.ended();
  ASSERT_TRUE(client.Send(Hello()));
  const auto reply = client.Next();
  ASSERT_TRUE(reply && reply->has_hello_reply()) << client.ended();
  const auto silent_since = Clock::now();  // from here the client touches nothing
  ASSERT_TRUE(LogShows(server, "closed: ERROR_CODE_IDLE_TIMEOUT", 30)) << server.Log();
  EXPECT_LT(std::chrono::duration<double>(Clock::now() - silent_since).count(), 1 + 2 + 10) << server.Log();
  // The socket is closed: its bytes (the Error, the close_notify) end in end of file.
  EXPECT_GE(SecondsUntilClosed(client.fd(), 5), 0);
  ExpectHelloWorks(server);
}

// The deadline itself, on the server's Transport in this process: a client whose receive
// window is full cannot take the close_notify, and the connection is closed at the deadline.
TEST_F(Tls, TheCloseNotifyDeadlineClosesAConnectionThatCannotTakeIt) {
  auto context = server::TlsContext::Load({.certificate_chain = pki_.server_cert, .private_key = pki_.server_key});
  ASSERT_TRUE(context.ok()) << context.status().ToString();
  net::io_context io;
  tcp::acceptor acceptor(io, tcp::endpoint(net::ip::address_v4::loopback(), 0));
  const std::uint16_t port = acceptor.local_endpoint().port();
  std::unique_ptr<StrictTlsClient> client;  // its handshake blocks: in a thread while `io` answers it
  std::thread connecting([&] { client = std::make_unique<StrictTlsClient>(port, pki_.ca); });
  tcp::socket accepted = acceptor.accept();
  const int fd = accepted.native_handle();
  const auto transport = server::MakeSocketTransport(std::move(accepted), context->get());
  boost::system::error_code handshake = net::error::would_block;
  transport->AsyncHandshake([&](const boost::system::error_code& ec) { handshake = ec; });
  io.run();
  connecting.join();
  ASSERT_FALSE(handshake) << handshake.message();
  ASSERT_TRUE(client->connected()) << client->ended();

  // Fill the send buffer and the client's window (raw bytes under TLS: the client reads none).
  const std::string junk(65536, 'x');
  while (send(fd, junk.data(), junk.size(), MSG_DONTWAIT | MSG_NOSIGNAL) > 0) {
  }
  ASSERT_TRUE(errno == EAGAIN || errno == EWOULDBLOCK) << std::strerror(errno);

  const auto deadline = std::chrono::milliseconds(300);
  const auto start = Clock::now();
  bool done = false;
  transport->AsyncCloseNotify(deadline, [&] { done = true; });
  io.restart();
  io.run_for(std::chrono::seconds(20));
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  EXPECT_TRUE(done);
  EXPECT_TRUE(fcntl(fd, F_GETFD) == -1 && errno == EBADF) << "the deadline closes the socket";
  EXPECT_GE(seconds, 0.3) << "closed before the deadline: the close_notify was sent after all?";
  EXPECT_LT(seconds, 10);
}

// tls.client_ca: only clients holding a certificate that CA signed get a session.
TEST_F(Tls, WithAClientCaOnlyClientsWithItsCertificatesGetIn) {
  ServerSettings s = Settings();
  s.sections_yaml += "  client_ca: " + pki_.ca + "\n";
  ServerProcess server(s);
  TlsClientOptions with_certificate = Trusting(pki_.ca);
  with_certificate.certificate = pki_.client_cert;
  with_certificate.private_key = pki_.client_key;
  ExpectHelloWorks(server, with_certificate);

  const std::vector<std::tuple<std::string, std::string, std::string>> refused{
      {"no certificate", "", ""}, {"a certificate another CA signed", other_.client_cert, other_.client_key}};
  for (const auto& [what, certificate, key] : refused) {
    TlsClientOptions o = Trusting(pki_.ca);
    o.certificate = certificate;
    o.private_key = key;
    // TLS 1.3 finishes the client's side of the handshake before the server has checked its
    // certificate: the refusal shows at the connect or at the first read.
    auto conn = Connection::Connect("127.0.0.1", server.port(), 10, 0, o);
    if (!conn.ok()) {
      EXPECT_NE(conn.status().message().find("TLS handshake"), std::string::npos) << what << ": " << conn.status().ToString();
      continue;
    }
    (void)conn->Send(Hello());
    const auto reply = conn->Receive(30);
    EXPECT_FALSE(reply.ok() && reply->has_hello_reply()) << what << " was let in";
  }
  EXPECT_NE(server.Log().find("TLS handshake failed"), std::string::npos) << server.Log();
  EXPECT_TRUE(server.alive());
}

TEST_F(Tls, TlsConfigErrorsNameTheFileAndTheProblem) {
  const auto check = [&](const std::string& tls_yaml) {
    const std::string path = dir_.path() + "/bad.yaml";
    std::ofstream(path) << "server:\n  address: 127.0.0.1\n" << tls_yaml << "robots:\n  - id: kr5\n    urdf: builtin\n";
    return RunCommand(arref::testing::kServerPath + " --check-config --config " + path);
  };
  const std::string missing = dir_.path() + "/missing.key";
  const auto no_key = check(TlsYaml(pki_.server_cert, missing));
  EXPECT_EQ(no_key.exit_code, 2);
  EXPECT_NE(no_key.err.find("tls.private_key " + missing + ": no such file"), std::string::npos) << no_key.err;

  const auto mismatched = check(TlsYaml(pki_.server_cert, other_.server_key));
  EXPECT_EQ(mismatched.exit_code, 2);
  EXPECT_NE(mismatched.err.find("tls.private_key " + other_.server_key + " does not match the certificate"),
            std::string::npos) << mismatched.err;

  const auto not_a_key = check(TlsYaml(pki_.server_cert, pki_.ca));
  EXPECT_EQ(not_a_key.exit_code, 2);
  EXPECT_NE(not_a_key.err.find("not an unencrypted PEM private key"), std::string::npos) << not_a_key.err;

  const auto half = check("tls:\n  certificate_chain: " + pki_.server_cert + "\n");
  EXPECT_EQ(half.exit_code, 2);
  EXPECT_NE(half.err.find("certificate_chain and private_key go together"), std::string::npos) << half.err;

  const auto good = check(TlsYaml(pki_.server_cert, pki_.server_key));
  EXPECT_EQ(good.exit_code, 0) << good.err;
}

TEST_F(Tls, AnAuthTokenIsRefusedInClearTextOffLoopbackUnlessAllowed) {
  const auto check = [&](const std::string& server_yaml, const std::string& sections = "") {
    const std::string path = dir_.path() + "/token.yaml";
    std::ofstream(path) << "server:\n  auth_token: s3cret\n" << server_yaml << sections
                        << "robots:\n  - id: kr5\n    urdf: builtin\n";
    return RunCommand(arref::testing::kServerPath + " --check-config --config " + path);
  };
  const auto refused = check("  address: 0.0.0.0\n");
  EXPECT_EQ(refused.exit_code, 2);
  EXPECT_NE(refused.err.find("not loopback: every headset's token would cross the network in clear text"),
            std::string::npos) << refused.err;
  EXPECT_NE(refused.err.find("allow_plaintext_token"), std::string::npos) << refused.err;

  const auto allowed = check("  address: 0.0.0.0\n  allow_plaintext_token: true\n");
  EXPECT_EQ(allowed.exit_code, 0) << allowed.err;
  EXPECT_NE(allowed.err.find("clear text"), std::string::npos) << "the risk is logged: " << allowed.err;

  EXPECT_EQ(check("  address: 127.0.0.1\n").exit_code, 0);
  EXPECT_EQ(check("  address: 0.0.0.0\n", TlsYaml(pki_.server_cert, pki_.server_key)).exit_code, 0);
  // The command line's address is the one that counts.
  const std::string path = dir_.path() + "/token.yaml";
  std::ofstream(path) << "server:\n  auth_token: s3cret\n  address: 127.0.0.1\nrobots:\n  - id: kr5\n    urdf: builtin\n";
  const auto overridden = RunCommand(arref::testing::kServerPath + " --check-config --address 0.0.0.0 --config " + path);
  EXPECT_EQ(overridden.exit_code, 2) << overridden.err;
}

}  // namespace
}  // namespace arref::headset
