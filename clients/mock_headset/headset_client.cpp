#include "headset_client.h"

#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <nlohmann/json.hpp>
#include <map>
#include <thread>

#include "arref/base/builtin.h"
#include "arref/base/clock.h"
#include "arref/base/stats.h"
#include "arref/pipeline/pipeline.h"
#include "arref/sim/cell_simulator.h"
#include "arref/sim/room_simulator.h"
#include "client_io.h"

namespace arref::headset {
namespace {

using Clock = std::chrono::steady_clock;
constexpr std::uint64_t kMaxReplyBytes = 1u << 30;

Status Errno(const std::string& what) { return Status(StatusCode::kUnavailable, what + ": " + std::strerror(errno)); }

timeval Timeval(double s) {
  timeval tv{};
  tv.tv_sec = static_cast<time_t>(s);
  tv.tv_usec = static_cast<suseconds_t>((s - static_cast<double>(tv.tv_sec)) * 1e6);
  return tv;
}

void SetTimeouts(int fd, double timeout_s) {
  const timeval tv = Timeval(timeout_s);
  setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);  // also bounds connect()
}

// Bounds a blocking read: a TLS record may be only partly here when poll() says readable.
void SetReceiveTimeout(int fd, double timeout_s) {
  const timeval tv = Timeval(std::max(timeout_s, 0.001));
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
}

}  // namespace

// ---------------------------------------------------------------- Connection

Result<Connection> Connection::Connect(const std::string& host, std::uint16_t port, double timeout_s,
                                       int rcvbuf_bytes, const TlsClientOptions& tls) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (int r = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &found); r != 0)
    return Status(StatusCode::kUnavailable, fmt::format("resolving {}: {}", host, gai_strerror(r)));
  Status last = Status(StatusCode::kUnavailable, "no address for " + host);
  for (addrinfo* a = found; a; a = a->ai_next) {
    const int fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    if (rcvbuf_bytes > 0) setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf_bytes, sizeof rcvbuf_bytes);
    SetTimeouts(fd, timeout_s);
    if (connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
      const int one = 1;
      setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      freeaddrinfo(found);
      Connection connection(fd);
      if (!tls.enabled) return connection;
      SetReceiveTimeout(fd, timeout_s);  // bounds the handshake
      ARREF_ASSIGN_OR_RETURN(connection.tls_, ClientTls::Handshake(fd, host, tls));
      return connection;
    }
    last = Errno(fmt::format("connecting to {}:{}", host, port));
    ::close(fd);
  }
  freeaddrinfo(found);
  return last;
}

Connection::Connection(Connection&& other) noexcept
    : fd_(other.fd_), rx_(std::move(other.rx_)), tls_(std::move(other.tls_)) {
  other.fd_ = -1;
}

Connection& Connection::operator=(Connection&& other) noexcept {
  if (this != &other) {
    Close();
    fd_ = other.fd_;
    rx_ = std::move(other.rx_);
    tls_ = std::move(other.tls_);
    other.fd_ = -1;
  }
  return *this;
}

Connection::~Connection() { Close(); }

void Connection::Close() {
  tls_.reset();
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void Connection::ShutdownWrite() {
  if (fd_ < 0) return;
  if (tls_) tls_->ShutdownWrite();
  ::shutdown(fd_, SHUT_WR);
}

Status Connection::Send(const pb::ClientMessage& message) { return SendRaw(wire::EncodeFrame(message)); }

Status Connection::SendRaw(const std::string& bytes) {
  if (fd_ < 0) return Status(StatusCode::kUnavailable, "not connected");
  if (tls_) return tls_->Write(bytes.data(), bytes.size());
  std::size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::send(fd_, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return Errno("sending");
    sent += static_cast<std::size_t>(n);
  }
  return Status::Ok();
}

Result<pb::ServerMessage> Connection::Receive(double timeout_s) {
  const auto deadline = Clock::now() + std::chrono::duration<double>(timeout_s);
  while (fd_ >= 0) {
    const auto h = wire::DecodeFrameHeader(reinterpret_cast<const std::uint8_t*>(rx_.data()), rx_.size(), kMaxReplyBytes);
    if (h.state == wire::FrameHeader::State::kTooLarge || h.state == wire::FrameHeader::State::kBadVarint)
      return Status(StatusCode::kInternal, "server sent an invalid frame header");
    if (h.state == wire::FrameHeader::State::kComplete && rx_.size() >= h.header_bytes + h.body_bytes) {
      pb::ServerMessage message;
      if (!message.ParseFromArray(rx_.data() + h.header_bytes, static_cast<int>(h.body_bytes)))
        return Status(StatusCode::kInternal, "server sent a frame that is not an arref.v1.ServerMessage");
      rx_.erase(0, h.header_bytes + h.body_bytes);
      return message;
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
    if (!tls_ || !tls_->Pending()) {
      pollfd p{fd_, POLLIN, 0};
      const int ready = ::poll(&p, 1, static_cast<int>(std::max<long long>(left, 0)));
      if (ready < 0 && errno == EINTR) continue;
      if (ready == 0) return Status::ResourceExhausted(fmt::format("no reply within {} s", timeout_s));
    }
    if (Status s = ReadSome(static_cast<double>(std::max<long long>(left, 1)) / 1000.0); !s.ok()) {
      if (s.code() != StatusCode::kResourceExhausted) return s;
      return Status::ResourceExhausted(fmt::format("no reply within {} s", timeout_s));
    }
  }
  return Status(StatusCode::kUnavailable, "not connected");
}

Status Connection::ReadSome(double timeout_s) {
  std::array<char, 65536> buf;
  if (tls_) {
    SetReceiveTimeout(fd_, timeout_s);
    ARREF_ASSIGN_OR_RETURN(const std::size_t n, tls_->Read(buf.data(), buf.size()));
    if (n == 0) return Status(StatusCode::kUnavailable, "server closed the connection");
    rx_.append(buf.data(), n);
    return Status::Ok();
  }
  const ssize_t n = ::recv(fd_, buf.data(), buf.size(), 0);
  if (n < 0 && errno == EINTR) return Status::Ok();
  if (n == 0) return Status(StatusCode::kUnavailable, "server closed the connection");
  if (n < 0) return Errno("receiving");
  rx_.append(buf.data(), static_cast<std::size_t>(n));
  return Status::Ok();
}

// ---------------------------------------------------------------- scenes

Result<HeadsetScene> SimulatedScene(std::uint64_t rng_seed) {
  ARREF_ASSIGN_OR_RETURN(const std::string urdf, BuiltinRobotUrdf());
  ARREF_ASSIGN_OR_RETURN(const RobotModel robot, RobotModel::Load(urdf));
  auto cell = sim::SimulateCell(robot, sim::SmallPreset(), rng_seed);
  if (!cell.ok()) return cell.status().WithContext("simulating a cell");
  HeadsetScene scene;
  scene.surfaces = std::move(cell->surfaces);
  scene.seeds = cell->seeds;
  scene.T_world_base_true = cell->T_world_base;
  scene.joints = cell->joints;
  scene.head_path_world = cell->head_path_world;
  ARREF_ASSIGN_OR_RETURN(PointCloud model, SampleRobot(robot, cell->joints, 5000, 7));
  scene.model_points = std::move(model.points);
  return scene;
}

Result<HeadsetScene> SimulatedRoomScene(std::uint64_t rng_seed, int arms, const std::string& mesher) {
  ARREF_ASSIGN_OR_RETURN(const std::string urdf, BuiltinRobotUrdf());
  ARREF_ASSIGN_OR_RETURN(const RobotModel robot, RobotModel::Load(urdf));
  sim::RoomOptions options;
  options.arms = arms;
  ARREF_ASSIGN_OR_RETURN(options.mesher, sim::ParseMesher(mesher));
  auto room = sim::SimulateRoom({&robot, nullptr}, options, rng_seed);
  if (!room.ok()) return room.status().WithContext("simulating a room");
  HeadsetScene scene;
  scene.surfaces = std::move(room->surfaces);
  scene.head_path_world = room->head_path_world;
  for (const sim::RoomArm& arm : room->arms) scene.arms_true.push_back(arm.T_world_base);
  // The arms share one joint state; with none, the robot's zero pose (a room without the arm).
  if (!room->arms.empty()) scene.joints = room->arms.front().joints;
  ARREF_ASSIGN_OR_RETURN(PointCloud model, SampleRobot(robot, scene.joints, 5000, 7));
  scene.model_points = std::move(model.points);
  return scene;
}

namespace {

// The cell file `arref simulate` writes: the truth, the seeds and where the wearer walked.
Status ReadTruth(const std::string& path, HeadsetScene* scene) {
  ARREF_ASSIGN_OR_RETURN(const nlohmann::json j, ReadJsonFile(path));
  auto T = MatrixFromJson(j.value("T_world_base", nlohmann::json()));
  if (!T.ok()) return T.status().WithContext(path + ": T_world_base");
  scene->T_world_base_true = *T;
  auto frame = FrameOfFile(j);
  if (!frame.ok()) return frame.status().WithContext(path);
  const nlohmann::json seeds = j.value("seeds", nlohmann::json::array());
  if (!seeds.is_array()) return Status::InvalidArgument(path + ": seeds must be an array of poses");
  for (std::size_t i = 0; i < seeds.size(); ++i) {
    auto seed = PoseFromJson(seeds[i], *frame);
    if (!seed.ok()) return seed.status().WithContext(path + ": seeds[" + std::to_string(i) + "]");
    scene->seeds.push_back(*seed);
  }
  if (j.contains("joints")) {
    auto joints = JointsFromJson(j["joints"]);
    if (!joints.ok()) return joints.status().WithContext(path);
    scene->joints = *joints;
  }
  if (j.contains("head_path")) {
    auto path_world = PositionsFromJson(j["head_path"], *frame);
    if (!path_world.ok()) return path_world.status().WithContext(path + ": head_path");
    scene->head_path_world = std::move(*path_world);
  }
  return Status::Ok();
}

}  // namespace

Result<HeadsetScene> SceneFromFiles(const std::string& mesh_path, FrameConvention mesh_frame,
                                    const std::string& truth_json, const std::optional<Iso3>& seed,
                                    const std::string& truth_robot_urdf, const RobotLoadOptions& truth_robot) {
  auto mesh = LoadMeshFile(mesh_path);
  if (!mesh.ok()) return mesh.status().WithContext("--scene");
  MeshToRos(*mesh, mesh_frame);
  HeadsetScene scene;
  scene.surfaces = SplitIntoSurfaces(*mesh, 1.0, 0.0);  // a mesh file carries no time
  if (!truth_json.empty()) ARREF_RETURN_IF_ERROR(ReadTruth(truth_json, &scene));
  if (seed) scene.seeds.insert(scene.seeds.begin(), *seed);
  if (scene.seeds.empty()) return Status::InvalidArgument("no seed: pass --seed or a --truth file with seeds");
  if (scene.T_world_base_true) {
    ARREF_ASSIGN_OR_RETURN(const std::string builtin, BuiltinRobotUrdf());
    auto robot = RobotModel::Load(truth_robot_urdf.empty() ? builtin : truth_robot_urdf, truth_robot);
    if (!robot.ok()) return robot.status().WithContext("--truth-robot");
    auto model = SampleRobot(*robot, scene.joints, 5000, 7);
    if (!model.ok()) return model.status().WithContext("the --truth cell's joints on the --truth-robot (is it the robot the cell was simulated with?)");
    scene.model_points = std::move(model->points);
  }
  return scene;
}

// ---------------------------------------------------------------- one headset

namespace {

class Runner {
 public:
  Runner(const HeadsetScene& scene, const HeadsetOptions& options, HeadsetRun* out)
      : scene_(scene), o_(options), out_(out) {}

  void Run() {
    if (!Connect() || !Handshake()) return;
    if (o_.misbehaviour == Misbehaviour::kOversizedMessage) return SendOversized();
    if (!Upload()) return;
    if (o_.misbehaviour == Misbehaviour::kCorruptFrame) return SendCorrupt();
    if (!SendSeedAndJoints()) return;
    for (int i = 0; i < o_.repeat; ++i) {
      if (i > 0 && o_.new_seed_each_repeat && !SendSeed(o_.seed_index + i)) return;
      if (!Register(o_.first_request_id + static_cast<std::uint64_t>(i))) return;
    }
    out_->status = Status::Ok();
  }

 private:
  bool Fail(Status status) {
    out_->status = std::move(status);
    return false;
  }
  bool Send(const pb::ClientMessage& m) {
    Status s = conn_.Send(m);
    if (!s.ok()) {
      out_->server_closed = true;
      return Fail(s.WithContext("sending"));
    }
    return true;
  }

  bool Connect() {
    const int rcvbuf = o_.misbehaviour == Misbehaviour::kNeverReadReplies ? 4096 : 0;
    auto conn = Connection::Connect(o_.host, o_.port, std::min(o_.timeout_s, 30.0), rcvbuf, o_.tls);
    if (!conn.ok()) return Fail(conn.status());
    conn_ = std::move(*conn);
    return true;
  }

  // Next message; records errors and shutdown notices. A fatal error or EOF ends the run.
  Result<pb::ServerMessage> Next(double timeout_s) {
    auto m = conn_.Receive(timeout_s);
    if (!m.ok()) {
      if (m.status().code() == StatusCode::kUnavailable) out_->server_closed = true;
      return m.status();
    }
    if (m->has_error()) {
      out_->errors.push_back(m->error());
      if (m->error().fatal())
        return Status(StatusCode::kUnavailable,
                      fmt::format("server closed the session: {}: {}", wire::ErrorCodeName(m->error().code()),
                                  m->error().message()));
    }
    if (m->has_shutdown()) out_->got_shutdown = true;
    return m;
  }

  // Reads whatever already arrived (e.g. rejected surfaces) without waiting.
  bool Drain() {
    while (true) {
      auto m = Next(0.0);
      if (m.ok()) continue;
      if (m.status().code() == StatusCode::kResourceExhausted) return true;
      return Fail(m.status());
    }
  }

  bool Handshake() {
    pb::ClientMessage m;
    m.mutable_hello()->set_protocol_version(o_.protocol_version);
    m.mutable_hello()->set_client_name(o_.client_name);
    m.mutable_hello()->set_auth_token(o_.auth_token);
    if (!Send(m)) return false;
    auto reply = Next(o_.timeout_s);
    if (!reply.ok()) return Fail(reply.status().WithContext("hello"));
    if (!reply->has_hello_reply()) return Fail(Status::Internal("expected HelloReply"));
    out_->session_id = reply->hello_reply().session_id();
    spdlog::debug("session {}: server {}", out_->session_id, reply->hello_reply().server_version());
    return true;
  }

  pb::ClientMessage SurfaceMessage(const Surface& s, double timestamp) const {
    pb::ClientMessage m;
    *m.mutable_surface_upsert() = wire::SurfaceToProto(s, FrameConvention::kUnity, o_.quantize_scale);
    m.mutable_surface_upsert()->set_timestamp_s(timestamp);
    return m;
  }

  bool Upload() {
    const auto& surfaces = scene_.surfaces;
    const int batches = std::max(o_.batches, 1);
    const std::size_t per_batch = (surfaces.size() + batches - 1) / batches;
    for (int b = 0; b < batches; ++b) {
      const std::size_t begin = std::min(surfaces.size(), b * per_batch);
      const std::size_t end = std::min(surfaces.size(), begin + per_batch);
      for (std::size_t i = begin; i < end; ++i) {
        if (o_.misbehaviour == Misbehaviour::kDisconnectMidUpload && i == surfaces.size() / 2) {
          conn_.Close();
          return Fail(Status::Cancelled(fmt::format("disconnected mid-upload after {} of {} surfaces (as asked)", i,
                                                    surfaces.size())));
        }
        if (!Send(SurfaceMessage(surfaces[i], b * o_.batch_interval_s))) return false;
      }
      if (b == batches - 1 && !ResendUpdates(std::min(per_batch, surfaces.size()), b)) return false;
      if (!Drain()) return false;
      if (b + 1 < batches) std::this_thread::sleep_for(std::chrono::duration<double>(o_.batch_interval_s));
    }
    return true;
  }

  // Some surfaces of the first batch come again, as the spatial mapper refines them.
  bool ResendUpdates(std::size_t first_batch_size, int batch) {
    const auto n = static_cast<std::size_t>(std::ceil(o_.resend_fraction * static_cast<double>(first_batch_size)));
    for (std::size_t i = 0; i < n && i < scene_.surfaces.size(); ++i)
      if (!Send(SurfaceMessage(scene_.surfaces[i], batch * o_.batch_interval_s + 0.01))) return false;
    return true;
  }

  // The scene's seed `index` (modulo their count) as the session's seed.
  bool SendSeed(int index) {
    if (scene_.seeds.empty()) return Fail(Status::InvalidArgument("the scene has no seed"));
    const Iso3& seed = scene_.seeds[static_cast<std::size_t>(index) % scene_.seeds.size()];
    pb::ClientMessage m;
    *m.mutable_seed_pose()->mutable_t_world_seed() = wire::PoseToProto(seed, FrameConvention::kUnity);
    m.mutable_seed_pose()->set_frame(pb::FRAME_CONVENTION_UNITY);
    return Send(m);
  }

  bool SendSeedAndJoints() {
    // A scene without seeds (a room) sends none: each request searches the whole map.
    if (!scene_.seeds.empty() && !SendSeed(o_.seed_index)) return false;
    if (scene_.joints.empty()) return true;
    pb::ClientMessage j;
    j.mutable_joint_state()->set_robot_id(o_.robot_id);
    for (const auto& [name, value] : scene_.joints) {
      j.mutable_joint_state()->add_names(name);
      j.mutable_joint_state()->add_positions(value);
    }
    return Send(j);
  }

  bool Register(std::uint64_t request_id) {
    pb::ClientMessage m;
    auto* r = m.mutable_register_request();
    r->set_request_id(request_id);
    r->set_robot_id(o_.robot_id);
    r->set_method(o_.method);
    r->set_result_frame(pb::FRAME_CONVENTION_UNITY);
    // As the app does: its wearer's path, logged while mapping, in Unity's frame.
    if (o_.send_head_path && !scene_.head_path_world.empty())
      *r->mutable_head_path() = wire::HeadPathToProto(scene_.head_path_world, FrameConvention::kUnity);
    if (!Send(m)) return false;
    const auto sent = Clock::now();
    if (o_.misbehaviour == Misbehaviour::kNeverReadReplies) return FloodWithoutReading();
    while (true) {
      auto reply = Next(o_.timeout_s);
      if (!reply.ok()) return Fail(reply.status().WithContext(fmt::format("request {}", request_id)));
      if (reply->has_progress() && reply->progress().request_id() == request_id && o_.on_progress)
        o_.on_progress(reply->progress());
      if (reply->has_error() && reply->error().request_id() == request_id)
        return Fail(Status(StatusCode::kFailedPrecondition,
                           fmt::format("request {} refused: {}: {}", request_id,
                                       wire::ErrorCodeName(reply->error().code()), reply->error().message())));
      if (reply->has_result() && reply->result().request_id() == request_id &&
          reply->result().session_id() == out_->session_id)
        return Finish(reply->result(), sent);
    }
  }

  // The pose's error against the room's arm nearest it.
  PoseError NearestArm(const Iso3& T_world_base) const {
    PoseError best;
    best.add_m = std::numeric_limits<double>::infinity();
    for (const Iso3& arm : scene_.arms_true)
      if (const PoseError e = ComparePoses(T_world_base, arm, scene_.model_points); e.add_m < best.add_m) best = e;
    return best;
  }

  bool Finish(const pb::Result& result, Clock::time_point sent) {
    RegistrationOutcome outcome;
    outcome.request_id = result.request_id();
    outcome.result = result;
    outcome.latency_ms = MsSince(sent);
    const bool has_pose = result.status() == pb::RESULT_STATUS_OK || result.status() == pb::RESULT_STATUS_LOW_CONFIDENCE;
    if (has_pose) {
      auto T = wire::PoseFromProto(result.t_world_base(), FrameConvention::kUnity);
      if (!T.ok()) return Fail(T.status().WithContext("result pose"));
      outcome.T_world_base = *T;
      if (scene_.T_world_base_true && !scene_.model_points.empty())
        outcome.error = ComparePoses(*T, *scene_.T_world_base_true, scene_.model_points);
      if (!scene_.arms_true.empty()) outcome.error = NearestArm(*T);
    }
    for (const pb::Candidate& c : result.candidates()) {
      auto T = wire::MatrixFromProto(c.t_world_base_internal());
      if (!T.ok()) return Fail(T.status().WithContext("result candidate pose"));
      if (!scene_.arms_true.empty()) outcome.candidate_add_m.push_back(NearestArm(*T).add_m);
    }
    out_->registrations.push_back(outcome);
    if (!has_pose)
      return Fail(Status(result.status() == pb::RESULT_STATUS_CANCELLED ? StatusCode::kCancelled
                                                                         : StatusCode::kFailedPrecondition,
                         fmt::format("request {}: {}: {}", result.request_id(), pb::ResultStatus_Name(result.status()),
                                     result.message())));
    return true;
  }

  // --never-read-replies: keep asking for big Pongs and never read them; a well-behaved
  // server drops this session once its send queue limit is reached.
  bool FloodWithoutReading() {
    pb::ClientMessage ping;
    ping.mutable_ping()->set_payload(std::string(60 * 1024, 'x'));
    for (int i = 0; i < 4000; ++i) {
      ping.mutable_ping()->set_nonce(static_cast<std::uint64_t>(i));
      if (!conn_.Send(ping).ok()) {
        out_->server_closed = true;
        return Fail(Status(StatusCode::kUnavailable,
                           fmt::format("the server dropped this session after {} unread Pings (as expected)", i)));
      }
    }
    return Fail(Status::Internal("the server kept a session that never reads (4000 Pings unread)"));
  }

  void SendOversized() {
    // A length prefix of 1 GiB followed by a little data: refused from the prefix alone.
    std::string bytes;
    std::uint64_t length = 1ull << 30;
    while (length >= 0x80) {
      bytes.push_back(static_cast<char>((length & 0x7f) | 0x80));
      length >>= 7;
    }
    bytes.push_back(static_cast<char>(length));
    bytes.append(4096, '\0');
    if (!conn_.SendRaw(bytes).ok()) {
      Fail(Status(StatusCode::kUnavailable, "server closed the connection during the oversized message"));
      return;
    }
    AwaitFatal("oversized message");
  }

  void SendCorrupt() {
    // Field 1 with wire type 7 does not exist: no protobuf parser accepts these 8 bytes.
    const std::string bytes("\x08\x0f\xff\xff\xff\xff\xff\xff\xff", 9);
    if (!conn_.SendRaw(bytes).ok()) {
      Fail(Status(StatusCode::kUnavailable, "server closed the connection during the corrupt frame"));
      return;
    }
    AwaitFatal("corrupt frame");
  }

  void AwaitFatal(const char* what) {
    while (true) {
      auto m = Next(o_.timeout_s);
      if (!m.ok()) {
        Fail(m.status().WithContext(std::string("after the ") + what));
        return;
      }
    }
  }

  const HeadsetScene& scene_;
  const HeadsetOptions& o_;
  HeadsetRun* out_;
  Connection conn_;
};

}  // namespace

HeadsetRun RunHeadset(const HeadsetScene& scene, const HeadsetOptions& options) {
  HeadsetRun run;
  run.status = Status::Internal("not run");
  Runner(scene, options, &run).Run();
  return run;
}

namespace {

// One recording sent to a server; answers are read while it waits for the next message's time.
class RecordingSender {
 public:
  RecordingSender(const wire::Recording& recording, const HeadsetOptions& options, Pace pace, HeadsetRun* out)
      : rec_(recording), o_(options), pace_(pace), out_(out) {}

  void Run() {
    auto conn = Connection::Connect(o_.host, o_.port, std::min(o_.timeout_s, 30.0), 0, o_.tls);
    if (!conn.ok()) {
      Fail(conn.status());
      return;
    }
    conn_ = std::move(*conn);
    if (!Hello()) return;
    const auto start = Clock::now();
    for (const auto& recorded : rec_.messages) {
      if (recorded.message().has_hello()) continue;
      const auto due = start + std::chrono::duration_cast<Clock::duration>(
                                   std::chrono::duration<double>(recorded.t_s() - hello_t_s_));
      if (pace_ == Pace::kOriginal && !ReadUntil(due)) return;
      if (recorded.message().has_register_request()) {
        const std::uint64_t rid = recorded.message().register_request().request_id();
        pending_.push_back(rid);
        sent_at_[rid] = Clock::now();
      }
      if (Status s = conn_.Send(recorded.message()); !s.ok()) {
        out_->server_closed = true;
        Fail(s.WithContext("sending the recording"));
        return;
      }
    }
    const auto deadline = Clock::now() + std::chrono::duration<double>(o_.timeout_s);
    while (!pending_.empty())
      if (!ReadOne(std::chrono::duration<double>(deadline - Clock::now()).count())) return;
    out_->status = Status::Ok();
    for (const auto& r : out_->registrations)
      if (r.result.status() != pb::RESULT_STATUS_OK && r.result.status() != pb::RESULT_STATUS_LOW_CONFIDENCE)
        out_->status = Status(StatusCode::kFailedPrecondition,
                              fmt::format("request {}: {}", r.request_id, pb::ResultStatus_Name(r.result.status())));
  }

 private:
  bool Fail(Status s) {
    out_->status = std::move(s);
    return false;
  }

  bool Hello() {
    for (const auto& recorded : rec_.messages)
      if (recorded.message().has_hello()) {
        hello_t_s_ = recorded.t_s();
        break;
      }
    pb::ClientMessage m;
    m.mutable_hello()->set_protocol_version(rec_.header.protocol_version());
    m.mutable_hello()->set_client_name(o_.client_name);
    m.mutable_hello()->set_auth_token(o_.auth_token);
    if (Status s = conn_.Send(m); !s.ok()) return Fail(s);
    auto reply = conn_.Receive(o_.timeout_s);
    if (!reply.ok()) return Fail(reply.status().WithContext("hello"));
    if (reply->has_error()) {
      out_->errors.push_back(reply->error());
      return Fail(Status(StatusCode::kUnavailable, fmt::format("hello refused: {}: {}",
                                                               wire::ErrorCodeName(reply->error().code()),
                                                               reply->error().message())));
    }
    out_->session_id = reply->hello_reply().session_id();
    return true;
  }

  // Handles answers until `until`.
  bool ReadUntil(Clock::time_point until) {
    while (true) {
      const double left = std::chrono::duration<double>(until - Clock::now()).count();
      if (left <= 0) return true;
      if (!ReadOne(left, /*timeout_is_ok=*/true)) return false;
    }
  }

  bool ReadOne(double timeout_s, bool timeout_is_ok = false) {
    auto m = conn_.Receive(std::max(timeout_s, 0.0));
    if (!m.ok()) {
      if (timeout_is_ok && m.status().code() == StatusCode::kResourceExhausted) return true;
      if (m.status().code() == StatusCode::kUnavailable) out_->server_closed = true;
      return Fail(m.status().WithContext(fmt::format("{} requests unanswered", pending_.size())));
    }
    if (m->has_error()) {
      out_->errors.push_back(m->error());
      std::erase(pending_, m->error().request_id());  // a refused request gets no Result
      if (m->error().fatal()) return Fail(Status(StatusCode::kUnavailable, m->error().message()));
    }
    if (m->has_shutdown()) out_->got_shutdown = true;
    if (m->has_result() && m->result().session_id() == out_->session_id) {
      RegistrationOutcome outcome;
      outcome.request_id = m->result().request_id();
      outcome.result = m->result();
      outcome.latency_ms = MsSince(sent_at_[outcome.request_id]);
      if (auto T = wire::MatrixFromProto(m->result().t_world_base_internal()); T.ok()) outcome.T_world_base = *T;
      out_->registrations.push_back(std::move(outcome));
      std::erase(pending_, m->result().request_id());
    }
    return true;
  }

  const wire::Recording& rec_;
  const HeadsetOptions& o_;
  Pace pace_;
  HeadsetRun* out_;
  Connection conn_;
  double hello_t_s_ = 0.0;
  std::vector<std::uint64_t> pending_;
  std::map<std::uint64_t, Clock::time_point> sent_at_;
};

}  // namespace

HeadsetRun SendRecording(const wire::Recording& recording, const HeadsetOptions& options, Pace pace) {
  HeadsetRun run;
  run.status = Status::Internal("not run");
  RecordingSender(recording, options, pace, &run).Run();
  return run;
}

std::vector<HeadsetRun> RunHeadsets(const HeadsetScene& scene, const HeadsetOptions& options, int clients) {
  std::vector<HeadsetRun> runs(static_cast<std::size_t>(clients));
  std::vector<HeadsetOptions> per_client(static_cast<std::size_t>(clients), options);
  std::vector<std::thread> threads;
  for (int i = 0; i < clients; ++i) {
    per_client[i].seed_index = options.seed_index + i;
    per_client[i].client_name = options.client_name + "-" + std::to_string(i);
    threads.emplace_back([&, i] { runs[i] = RunHeadset(scene, per_client[i]); });
  }
  for (auto& t : threads) t.join();
  return runs;
}

LatencySummary SummarizeLatency(const std::vector<HeadsetRun>& runs) {
  std::vector<double> ms;
  for (const auto& run : runs)
    for (const auto& r : run.registrations)
      if (r.result.status() == pb::RESULT_STATUS_OK) ms.push_back(r.latency_ms);
  LatencySummary s;
  s.count = ms.size();
  if (ms.empty()) return s;
  // stats.h's quantiles, so that these figures mean what the bench's tables mean.
  s.median_ms = Quantile(ms, 0.5), s.p95_ms = Quantile(ms, 0.95), s.max_ms = Quantile(ms, 1.0);
  return s;
}

}  // namespace arref::headset
