#include "session.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <new>

#include "arref/base/clock.h"
#include "convert.h"
#include "request_builder.h"
#include "tracking_messages.h"

namespace arref::server {
namespace {

namespace pb = wire::pb;

constexpr std::size_t kReadChunk = 64 * 1024;
constexpr auto kLinger = std::chrono::seconds(2);  // time to flush a final error before closing
// Time to send TLS close_notify once the replies are out (kLinger + this < the server's
// kFlushGrace at shutdown).
constexpr auto kCloseNotifyDeadline = std::chrono::seconds(2);

std::chrono::milliseconds Seconds(double s) { return std::chrono::milliseconds(static_cast<long long>(s * 1000)); }

}  // namespace

// ---------------------------------------------------------------- Session: life cycle

Session::Session(tcp::socket socket, ServerContext& context, std::uint64_t id)
    : Session(MakeSocketTransport(std::move(socket), context.tls), context, id) {}

Session::Session(std::unique_ptr<Transport> transport, ServerContext& context, std::uint64_t id)
    : transport_(std::move(transport)),
      ctx_(context),
      id_(id),
      handshaking_(transport_->encrypted()),
      peer_(transport_->peer()),
      rx_(std::min(kMaxHelloBytes, context.config.limits.max_message_bytes), 4 * kReadChunk),
      idle_timer_(transport_->executor()),
      hello_timer_(transport_->executor()),
      frame_timer_(transport_->executor()),
      write_timer_(transport_->executor()),
      linger_timer_(transport_->executor()) {
  connected_unix_s_ = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

Session::~Session() { spdlog::debug("session {} destroyed", id_); }

void Session::Start() {
  net::dispatch(transport_->executor(), [self = shared_from_this()] {
    spdlog::info("session {}: connected from {}{}", self->id_, self->peer_, self->transport_->encrypted() ? " (TLS)" : "");
    self->ArmIdleTimer();
    self->ArmHelloTimer();
    if (self->transport_->encrypted())
      self->StartTls();
    else
      self->ReadMore();
  });
}

void Session::StartTls() {
  transport_->AsyncHandshake([self = shared_from_this()](const boost::system::error_code& ec) {
    self->OnTlsHandshake(ec);
  });
}

// A failed handshake is the client's (plaintext, or it does not trust our certificate, or it
// has none that tls.client_ca signed): that connection closes, nothing else notices.
void Session::OnTlsHandshake(const boost::system::error_code& ec) {
  if (state_ >= State::kClosing) return;
  if (ec) {
    const std::string refused = transport_->PeerVerifyError();
    const std::string why = ec.message() + (refused.empty() ? "" : " (the client's certificate: " + refused + ")");
    spdlog::warn("session {} ({}): TLS handshake failed: {}", id_, peer_, why);
    return CloseNow("TLS handshake failed: " + why);
  }
  handshaking_ = false;
  ReadMore();
}

void Session::Reject(pb::ErrorCode code, const std::string& message) {
  net::dispatch(transport_->executor(), [self = shared_from_this(), code, message] {
    self->FailAndClose(code, message);
  });
}

void Session::ArmIdleTimer() {
  idle_timer_.expires_after(Seconds(ctx_.config.idle_timeout_s));
  idle_timer_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
    if (ec || self->state_ >= State::kClosing) return;
    if (!self->in_flight_.empty()) {  // waiting for our own results is not idleness
      self->ArmIdleTimer();
      return;
    }
    self->FailAndClose(pb::ERROR_CODE_IDLE_TIMEOUT,
                       fmt::format("nothing received for {} s (server.idle_timeout_s); send Ping to keep a session open",
                                   self->ctx_.config.idle_timeout_s));
  });
}

// Connections that never say Hello must not hold a slot: they get hello_timeout_s, the TLS
// handshake included.
void Session::ArmHelloTimer() {
  hello_timer_.expires_after(Seconds(ctx_.config.hello_timeout_s));
  hello_timer_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
    if (ec || self->state_ != State::kAwaitHello) return;
    self->FailAndClose(pb::ERROR_CODE_HANDSHAKE_TIMEOUT,
                       fmt::format("no {} within {} s of connecting (server.hello_timeout_s)",
                                   self->handshaking_ ? "completed TLS handshake" : "Hello",
                                   self->ctx_.config.hello_timeout_s));
  });
}

// A frame must arrive whole within frame_timeout_s of its first byte, so that a client cannot
// hold a connection (or a buffer) by trickling one frame forever. The clock restarts with
// every frame that completes.
void Session::UpdateFrameTimer(bool frame_completed) {
  if (rx_.buffered_bytes() == 0 && !rx_.skipping()) {
    if (frame_timer_armed_) frame_timer_.cancel();
    frame_timer_armed_ = false;
    return;
  }
  if (frame_timer_armed_ && !frame_completed) return;  // the same frame is still arriving
  frame_timer_armed_ = true;
  frame_timer_.expires_after(Seconds(ctx_.config.frame_timeout_s));
  frame_timer_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
    if (ec || self->state_ >= State::kClosing) return;
    const std::uint64_t declared = self->rx_.PendingBodyBytes();
    self->FailAndClose(
        pb::ERROR_CODE_FRAME_TIMEOUT,
        fmt::format("a message did not arrive whole within {} s of its first byte (server.frame_timeout_s): {} bytes "
                    "received{}", self->ctx_.config.frame_timeout_s, self->rx_.buffered_bytes(),
                    declared > 0 ? fmt::format(" of {} announced", declared) : std::string(" (length prefix incomplete)")));
  });
}

// ---------------------------------------------------------------- reading

void Session::ReadMore() {
  if (state_ >= State::kClosing) return;
  const auto space = rx_.Buffer(kReadChunk);
  reading_ = true;
  transport_->AsyncReadSome(net::buffer(space.data(), space.size()),
                           [self = shared_from_this()](const boost::system::error_code& ec, std::size_t n) {
                             self->OnRead(ec, n);
                           });
}

void Session::OnRead(const boost::system::error_code& ec, std::size_t bytes) {
  reading_ = false;
  if (state_ >= State::kClosing) {
    if (finishing_) FinishClosing();
    return;
  }
  if (ec) return OnReadEnd(ec);
  try {
    rx_.Commit(bytes);
    ArmIdleTimer();
    if (ProcessFrames()) ReadMore();
  } catch (const std::bad_alloc&) {  // the buffer or a parse: the stream cannot go on
    FailAndClose(pb::ERROR_CODE_LIMIT_EXCEEDED, "out of memory receiving a message (std::bad_alloc)");
  }
}

// A half-closed client (shutdown(SHUT_WR)) still gets the results of its accepted requests;
// the session closes once they are written.
void Session::OnReadEnd(const boost::system::error_code& ec) {
  if (!Transport::IsEndOfStream(ec)) return CloseNow("read failed: " + ec.message());
  if (state_ == State::kReady && !in_flight_.empty()) {
    read_closed_ = true;
    if (frame_timer_armed_) frame_timer_.cancel();
    spdlog::info("session {}: client closed its side; delivering {} results still in flight", id_, in_flight_.size());
    return;
  }
  StartClosing("client closed the connection");  // sends what is queued first
}

// Large frames are charged to the memory budget as soon as their length is known; one that
// does not fit is dropped as it arrives, with an error, and the session goes on.
bool Session::ChargeNextFrame() {
  if (state_ != State::kReady || frame_memory_.bytes() > 0 || rx_.skipping()) return true;
  const std::uint64_t declared = rx_.PendingBodyBytes();
  if (declared < kChargedFrameBytes) return true;
  auto reserved = ctx_.memory.Reserve(static_cast<std::size_t>(declared) * kFrameExpansion,
                                      fmt::format("a message of {} bytes", declared));
  if (reserved.ok()) {
    frame_memory_ = std::move(*reserved);
    return true;
  }
  rx_.SkipNext();
  SendError(pb::ERROR_CODE_LIMIT_EXCEEDED,
            reserved.status().message() + "; the message is dropped unread and the session keeps what it had");
  return false;
}

bool Session::ProcessFrames() {
  using Kind = wire::FrameDecoder::Frame::Kind;
  bool completed = false;
  while (state_ < State::kClosing) {
    ChargeNextFrame();
    const wire::FrameDecoder::Frame f = rx_.Next();
    if (f.kind == Kind::kNeedMore) break;
    completed = true;
    if (f.kind == Kind::kSkipped) continue;
    if (f.kind == Kind::kTooLarge) {
      const std::size_t limit = ctx_.config.limits.max_message_bytes;
      FailAndClose(pb::ERROR_CODE_MESSAGE_TOO_LARGE,
                   state_ == State::kAwaitHello
                       ? fmt::format("message of {} bytes before Hello exceeds the limit of {} bytes for it", f.body_bytes,
                                     std::min(kMaxHelloBytes, limit))
                       : fmt::format("message of {} bytes exceeds the limit of {} bytes (limits.max_message_bytes)",
                                     f.body_bytes, limit));
      return false;
    }
    if (f.kind == Kind::kBadVarint) {
      FailAndClose(pb::ERROR_CODE_MALFORMED_MESSAGE, "invalid varint length prefix");
      return false;
    }
    pb::ClientMessage message;
    if (!message.ParseFromArray(f.body.data(), static_cast<int>(f.body.size()))) {
      FailAndClose(pb::ERROR_CODE_MALFORMED_MESSAGE,
                   fmt::format("a frame of {} bytes does not parse as arref.v1.ClientMessage", f.body_bytes));
      return false;
    }
    Record(message);  // a Hello is recorded by OnHello, once accepted
    Handle(message);
    frame_memory_.Release();
  }
  if (state_ < State::kClosing) UpdateFrameTimer(completed);
  return state_ < State::kClosing;
}

// ---------------------------------------------------------------- dispatch

void Session::Handle(const pb::ClientMessage& m) {
  using K = pb::ClientMessage::KindCase;
  if (state_ == State::kAwaitHello && m.kind_case() != K::kHello) {
    FailAndClose(pb::ERROR_CODE_NOT_READY, "the first message must be Hello (protocol version handshake)");
    return;
  }
  try {
    switch (m.kind_case()) {
      case K::kHello: OnHello(m.hello()); break;
      case K::kSurfaceUpsert: OnSurfaceUpsert(m.surface_upsert()); break;
      case K::kSurfaceRemove: OnSurfaceRemove(m.surface_remove()); break;
      case K::kSeedPose: OnSeedPose(m.seed_pose()); break;
      case K::kJointState: OnJointState(m.joint_state()); break;
      case K::kRegisterRequest: OnRegisterRequest(m.register_request()); break;
      case K::kCancel: OnCancel(m.cancel()); break;
      case K::kSubscribe: OnSubscribe(m.subscribe()); break;
      case K::kPing: OnPing(m.ping()); break;
      case K::kDepthFrame: OnDepthFrame(m.depth_frame()); break;
      case K::kTrackRequest: OnTrackRequest(m.track_request()); break;
      case K::kClockReport: OnClockReport(m.clock_report()); break;
      case K::KIND_NOT_SET:
        SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "message has no known kind (newer client?); ignored");
        break;
    }
  } catch (const std::bad_alloc&) {  // the budget's estimates were short: drop this message only
    spdlog::error("session {}: out of memory handling message {}", id_, static_cast<int>(m.kind_case()));
    SendError(pb::ERROR_CODE_LIMIT_EXCEEDED,
              "out of memory handling this message (std::bad_alloc): it is dropped, the session keeps what it had");
  } catch (const std::exception& e) {  // a bug on one message must not end the server
    spdlog::error("session {}: handling message {} threw: {}", id_, static_cast<int>(m.kind_case()), e.what());
    SendError(pb::ERROR_CODE_INTERNAL, std::string("internal error: ") + e.what());
  }
}

void Session::OnHello(const pb::Hello& m) {
  if (state_ != State::kAwaitHello) {
    SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "Hello sent twice; ignored");
    return;
  }
  if (m.protocol_version() != wire::kProtocolVersion) {
    FailAndClose(pb::ERROR_CODE_VERSION_MISMATCH,
                 fmt::format("client speaks protocol version {}, this server speaks version {} (arref.v1)",
                             m.protocol_version(), wire::kProtocolVersion));
    return;
  }
  if (!ctx_.config.auth_token.empty() && m.auth_token() != ctx_.config.auth_token) {
    FailAndClose(pb::ERROR_CODE_UNAUTHENTICATED, "auth token missing or wrong");
    return;
  }
  if (Status admitted = ctx_.on_hello ? ctx_.on_hello(id_) : Status::Ok(); !admitted.ok()) {
    FailAndClose(pb::ERROR_CODE_LIMIT_EXCEEDED, admitted.message());
    return;
  }
  state_ = State::kReady;
  hello_timer_.cancel();
  rx_.set_max_body_bytes(ctx_.config.limits.max_message_bytes);
  client_name_ = m.client_name();
  spdlog::info("session {}: hello from '{}' ({})", id_, client_name_, peer_);
  pb::ServerMessage reply;
  FillHelloReply(reply.mutable_hello_reply());
  Send(reply);
  if (!ctx_.config.record_dir.empty()) {
    pb::ClientMessage hello;
    *hello.mutable_hello() = m;
    StartRecording(reply.hello_reply(), hello);
  }
  if (ctx_.shutting_down) NotifyShutdown(ctx_.config.shutdown_grace_s);
}

void Session::FillHelloReply(pb::HelloReply* r) const {
  r->set_protocol_version(wire::kProtocolVersion);
  r->set_server_version(ctx_.server_version);
  r->set_session_id(id_);
  for (const auto& robot : ctx_.robots.robots()) {
    auto* info = r->add_robots();
    info->set_id(robot->config.id);
    info->set_name(robot->model.name());
    info->set_base_link(robot->model.root_link());
    for (const auto& j : robot->model.ActuatedJoints()) {
      info->add_joint_names(j.name);
      info->add_default_positions(robot->default_joints.at(j.name));
    }
  }
  for (const auto& name : MethodNames()) r->add_methods(name);
  r->set_default_method(MethodName(ctx_.config.registration.method));
  const ServerConfig& c = ctx_.config;
  const ServerLimits& l = c.limits;
  pb::Limits* out = r->mutable_limits();
  out->set_max_message_bytes(l.max_message_bytes);
  out->set_max_hello_bytes(std::min(kMaxHelloBytes, l.max_message_bytes));
  out->set_max_sessions(l.max_sessions);
  out->set_max_pending_connections(l.max_pending_connections);
  out->set_max_connections_per_peer(l.max_connections_per_peer);
  out->set_max_surfaces_per_session(l.max_surfaces_per_session);
  out->set_max_vertices_per_session(l.max_vertices_per_session);
  out->set_max_triangles_per_session(l.max_triangles_per_session);
  out->set_max_mesh_bytes_per_session(l.max_mesh_bytes_per_session);
  out->set_memory_budget_bytes(l.memory_budget_bytes);
  out->set_max_requests_per_session(l.max_requests_per_session);
  out->set_queue_size(c.queue_size);
  out->set_max_ping_payload_bytes(kMaxPingPayload);
  out->set_max_head_path_positions(kMaxHeadPathPositions);
  out->set_hello_timeout_s(c.hello_timeout_s);
  out->set_frame_timeout_s(c.frame_timeout_s);
  out->set_idle_timeout_s(c.idle_timeout_s);
  out->set_workers(static_cast<std::uint32_t>(c.workers));
  out->set_max_map_triangles(l.max_map_triangles);
  for (const ParamRange& range : kParamRanges) {
    pb::ParamRange* p = out->add_params();
    p->set_name(range.name);
    p->set_min(range.min);
    p->set_max(range.max);
  }
}

void Session::OnSurfaceUpsert(const pb::SurfaceUpsert& m) {
  const std::uint64_t sid = m.surface_id();
  // Sizes from the message, so that limits are checked before anything is converted.
  const std::size_t vertices = static_cast<std::size_t>(std::max(m.vertices_size(), m.quantized_vertices_size())) / 3;
  const std::size_t triangles = static_cast<std::size_t>(m.triangles_size()) / 3;
  auto memory = AdmitSurface(sid, vertices, triangles);
  if (!memory.ok())
    return SendError(pb::ERROR_CODE_LIMIT_EXCEEDED, fmt::format("surface {} rejected: {}", sid, memory.status().message()),
                     0, sid);
  auto surface = wire::SurfaceFromProto(m);
  if (!surface.ok()) {
    SendError(pb::ERROR_CODE_BAD_SURFACE, fmt::format("surface {} rejected: {}", sid, surface.status().message()), 0,
              sid);
    return;
  }
  const auto old = spatial_.surfaces().find(sid);
  const std::size_t old_triangles = old != spatial_.surfaces().end() ? old->second.mesh.triangles.size() : 0;
  const std::size_t old_bytes = old != spatial_.surfaces().end() ? MeshBytes(old->second.mesh) : 0;
  const std::size_t new_bytes = MeshBytes(surface->mesh);
  const std::size_t new_triangles = surface->mesh.triangles.size();
  if (Status s = spatial_.Upsert(std::move(*surface)); !s.ok())
    return SendError(pb::ERROR_CODE_BAD_SURFACE, fmt::format("surface {} rejected: {}", sid, s.message()), 0, sid);
  triangles_ = triangles_ - old_triangles + new_triangles;
  mesh_bytes_ = mesh_bytes_ - old_bytes + new_bytes;
  surface_memory_[sid] = std::move(*memory);  // releases the replaced surface's charge
}

Result<MemoryBudget::Reservation> Session::AdmitSurface(std::uint64_t sid, std::size_t vertices, std::size_t triangles) {
  const ServerLimits& limits = ctx_.config.limits;
  const auto old = spatial_.surfaces().find(sid);
  const bool replaces = old != spatial_.surfaces().end();
  const std::size_t surfaces_after = spatial_.size() + (replaces ? 0 : 1);
  const std::size_t vertices_after =
      spatial_.vertex_count() - (replaces ? old->second.mesh.vertices.size() : 0) + vertices;
  const std::size_t triangles_after = triangles_ - (replaces ? old->second.mesh.triangles.size() : 0) + triangles;
  const std::size_t bytes = MeshBytes(vertices, triangles);
  const std::size_t bytes_after = mesh_bytes_ - (replaces ? MeshBytes(old->second.mesh) : 0) + bytes;
  struct Check {
    std::size_t after, limit;
    const char* what;
    const char* key;
  };
  for (const Check& c : {Check{surfaces_after, limits.max_surfaces_per_session, "surfaces", "max_surfaces_per_session"},
                         Check{vertices_after, limits.max_vertices_per_session, "vertices", "max_vertices_per_session"},
                         Check{triangles_after, limits.max_triangles_per_session, "triangles", "max_triangles_per_session"},
                         Check{bytes_after, limits.max_mesh_bytes_per_session, "mesh bytes", "max_mesh_bytes_per_session"}})
    if (c.after > c.limit)
      return Status::ResourceExhausted(
          fmt::format("the session would hold {} {}, limit {} (limits.{})", c.after, c.what, c.limit, c.key));
  return ctx_.memory.Reserve(bytes, fmt::format("a surface of {} vertices and {} triangles", vertices, triangles));
}

void Session::OnSurfaceRemove(const pb::SurfaceRemove& m) {
  const auto it = spatial_.surfaces().find(m.surface_id());
  if (it == spatial_.surfaces().end())
    return SendError(pb::ERROR_CODE_UNKNOWN_SURFACE,
                     fmt::format("surface {} is not held by this session", m.surface_id()), 0, m.surface_id());
  triangles_ -= it->second.mesh.triangles.size();
  mesh_bytes_ -= MeshBytes(it->second.mesh);
  spatial_.Remove(m.surface_id());
  surface_memory_.erase(m.surface_id());
}

void Session::OnSeedPose(const pb::SeedPose& m) {
  const auto frame = wire::FromProto(m.frame());
  if (!frame.ok()) return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose: " + frame.status().message());
  auto T = wire::PoseFromProto(m.t_world_seed(), *frame);
  if (!T.ok()) return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose.T_world_seed: " + T.status().message());
  seed_ = *T;
  seed_frame_ = *frame;
}

// The latest JointState for a robot id replaces the earlier one; a rejected one is kept as
// rejected, so that requests which would use it fail instead of running on defaults.
void Session::OnJointState(const pb::JointState& m) {
  JointStateOutcome outcome = ReadJointState(m, ctx_.robots);
  if (outcome.error != pb::ERROR_CODE_UNSPECIFIED) SendError(outcome.error, outcome.message);
  if (!outcome.keep) return;
  const JointValues& joints = outcome.joints.values;
  if (outcome.joints.rejected.empty()) {
    if (auto refused = FeedJointStream(m, outcome.complete, ctx_.tracking, id_))
      SendError(refused->code, refused->message);
    if (spatial_.size() > 0) mapping_motion_.Add(m.robot_id(), joints);
  }
  joints_[m.robot_id()] = std::move(outcome.joints);
}

void Session::OnTrackRequest(const pb::TrackRequest& m) {
  if (auto refused = HandleTrackRequest(m, ctx_.robots, ctx_.tracking, shared_from_this(), seed_))
    SendError(refused->code, refused->message);
}

void Session::OnDepthFrame(const pb::DepthFrame& m) {
  if (auto refused = HandleDepthFrame(m, ctx_.tracking, id_)) SendError(refused->code, refused->message);
}

void Session::OnClockReport(const pb::ClockReport& m) {
  if (auto refused = HandleClockReport(m, ctx_.tracking, id_)) SendError(refused->code, refused->message);
}

void Session::OnCancel(const pb::Cancel& m) {
  if (m.request_id() == 0)
    return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "Cancel.request_id must be >= 1 (0 is never a request id)");
  std::shared_ptr<Job> removed;
  switch (ctx_.jobs.Cancel(id_, m.request_id(), &removed)) {
    case JobScheduler::CancelResult::kRemovedFromQueue:
      spdlog::info("session {}: request {} cancelled while queued", id_, m.request_id());
      FinishCancelled(*removed, "cancelled by the client while queued");
      break;
    case JobScheduler::CancelResult::kFlaggedRunning:
      spdlog::info("session {}: request {} cancel requested while running", id_, m.request_id());
      break;  // its token is cancelled: the worker answers CANCELLED when the pipeline stops
    case JobScheduler::CancelResult::kNotFound:
      SendError(pb::ERROR_CODE_UNKNOWN_REQUEST,
                fmt::format("request {} is not in flight (never accepted or already answered)", m.request_id()),
                m.request_id());
      break;
  }
}

void Session::OnSubscribe(const pb::Subscribe& m) {
  if (!ctx_.robots.Find(m.robot_id()))
    return SendError(pb::ERROR_CODE_UNKNOWN_ROBOT, fmt::format("Subscribe: robot '{}' is not served here (served: {})",
                                                               m.robot_id(), ctx_.robots.Ids()));
  ctx_.hub.Set(m.robot_id(), shared_from_this(), !m.unsubscribe());
  pb::ServerMessage reply;
  reply.mutable_subscribed()->set_robot_id(m.robot_id());
  reply.mutable_subscribed()->set_subscribed(!m.unsubscribe());
  Send(reply);
}

void Session::OnPing(const pb::Ping& m) {
  if (m.payload().size() > kMaxPingPayload)
    return SendError(pb::ERROR_CODE_INVALID_ARGUMENT,
                     fmt::format("Ping payload of {} bytes exceeds {} bytes", m.payload().size(), kMaxPingPayload));
  const double received = TrackingService::Now();
  pb::ServerMessage reply;
  reply.mutable_pong()->set_nonce(m.nonce());
  reply.mutable_pong()->set_client_time_s(m.client_time_s());
  reply.mutable_pong()->set_receive_time_s(received);
  reply.mutable_pong()->set_payload(m.payload());
  reply.mutable_pong()->set_server_time_s(TrackingService::Now());
  Send(reply);
}

// ---------------------------------------------------------------- registration requests

void Session::OnRegisterRequest(const pb::RegisterRequest& m) {
  const std::uint64_t rid = m.request_id();
  if (rid == 0)
    return SendError(pb::ERROR_CODE_INVALID_ARGUMENT,
                     "RegisterRequest.request_id must be >= 1 (0 cannot be told from unset in the answer)");
  if (ctx_.shutting_down)
    return SendError(pb::ERROR_CODE_SHUTTING_DOWN, "the server is shutting down; request not accepted", rid);
  if (in_flight_.count(rid))
    return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, fmt::format("request id {} is already in flight", rid), rid);
  if (in_flight_.size() >= ctx_.config.limits.max_requests_per_session)
    return SendError(pb::ERROR_CODE_LIMIT_EXCEEDED,
                     fmt::format("{} requests already in flight, limit {} (limits.max_requests_per_session)",
                                 in_flight_.size(), ctx_.config.limits.max_requests_per_session), rid);
  std::shared_ptr<Job> job = MakeJob(m);
  if (!job) return;
  QueueInfo queue;
  switch (ctx_.jobs.Submit(job, nullptr, &queue)) {
    case JobScheduler::SubmitResult::kFull:
      spdlog::warn("session {}: request {} refused: queue full", id_, rid);
      return SendError(pb::ERROR_CODE_BUSY,
                       fmt::format("server busy: the job queue is full ({} waiting, server.queue_size); retry later",
                                   ctx_.config.queue_size), rid);
    case JobScheduler::SubmitResult::kClosed:
      return SendError(pb::ERROR_CODE_SHUTTING_DOWN, "the server is shutting down; request not accepted", rid);
    case JobScheduler::SubmitResult::kQueued: break;
  }
  in_flight_.insert(rid);  // results arrive through a post, so after this handler
  spdlog::info("session {}: request {} accepted for robot '{}' at queue position {} (estimated wait {:.0f} ms; this "
               "session's earlier requests waited {:.0f} ms on average over {})", id_, rid, m.robot_id(), queue.position,
               queue.estimated_wait_ms, queue.session_queue_ms, queue.session_jobs_started);
  pb::ServerMessage reply;
  reply.mutable_accepted()->set_request_id(rid);
  reply.mutable_accepted()->set_queue_position(static_cast<std::uint32_t>(queue.position));
  reply.mutable_accepted()->set_estimated_wait_ms(queue.estimated_wait_ms);
  reply.mutable_accepted()->set_session_queue_ms(queue.session_queue_ms);
  Send(reply);
}

std::shared_ptr<Job> Session::MakeJob(const pb::RegisterRequest& m) {
  const std::uint64_t rid = m.request_id();
  auto job = BuildJob(m, ctx_.robots, ctx_.config.registration,
                      SessionDefaults{.seed = seed_, .seed_frame = seed_frame_, .joints = &joints_});
  if (!job.ok()) {
    SendError(RequestErrorCode(job.status()), job.status().message(), rid);
    return nullptr;
  }
  if (spatial_.size() == 0) {
    SendError(pb::ERROR_CODE_NO_SCENE, "the session holds no surfaces: send SurfaceUpsert messages first", rid);
    return nullptr;
  }
  auto memory = ctx_.memory.Reserve(JobBytes(mesh_bytes_, (*job)->options.scene_samples),
                                    fmt::format("request {} (a scene of {} triangles)", rid, triangles_));
  if (!memory.ok()) {
    SendError(pb::ERROR_CODE_LIMIT_EXCEEDED, memory.status().message(), rid);
    return nullptr;
  }
  (*job)->memory = std::move(*memory);
  (*job)->session_id = id_;
  (*job)->scene_world = spatial_.MergedWorld();
  (*job)->joints_while_mapping = mapping_motion_.For((*job)->robot_id, ctx_.robots.Find((*job)->robot_id)->model);
  (*job)->scene_time_unix_s =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  for (const auto& [sid, surface] : spatial_.surfaces())
    (*job)->scene_headset_time_s = std::max((*job)->scene_headset_time_s, surface.timestamp_s);
  // A seedless search takes the whole map: its size is bounded (the surfaces stay).
  const std::size_t triangles = (*job)->scene_world->triangles.size();
  if ((*job)->seedless && triangles > ctx_.config.limits.max_map_triangles) {
    SendError(pb::ERROR_CODE_LIMIT_EXCEEDED,
              fmt::format("the map holds {} triangles, over limits.max_map_triangles = {} for a search of the whole map; "
                          "send a seed (SeedPose or RegisterRequest.seed) or remove surfaces",
                          triangles, ctx_.config.limits.max_map_triangles), rid);
    return nullptr;
  }
  AttachCallbacks(**job);
  return std::move(*job);
}

void Session::AttachCallbacks(Job& job) {
  std::weak_ptr<Session> weak = shared_from_this();
  SubscriberHub* hub = &ctx_.hub;
  const std::uint64_t rid = job.request_id;
  job.on_progress = [weak, rid](std::string_view stage, double fraction) {
    auto self = weak.lock();
    if (!self) return;
    pb::ServerMessage message;
    message.mutable_progress()->set_request_id(rid);
    message.mutable_progress()->set_stage(std::string(stage));
    message.mutable_progress()->set_fraction(fraction);
    self->SendFrame(wire::SharedFrame(message));
  };
  job.on_done = [weak, hub](const Job& done, const JobOutcome& outcome) {
    const wire::ResultHeader header{.request_id = done.request_id,
                                    .robot_id = done.robot_id,
                                    .session_id = done.session_id,
                                    .queue_ms = outcome.queue_ms,
                                    .server_ms = MsSince(done.accepted_at),
                                    .scene_time_unix_s = done.scene_time_unix_s,
                                    .scene_headset_time_s = done.scene_headset_time_s};
    pb::ServerMessage message = wire::ResultMessage(header, outcome.report, outcome.status, done.result_frame);
    if (outcome.seedless)
      wire::FillCandidates(outcome.instances, outcome.primary, done.result_frame, message.mutable_result());
    AddMappingMotion(done.joints_while_mapping, outcome, message.mutable_result());
    const auto frame = wire::SharedFrame(message);
    spdlog::info("session {}: request {} {} ({:.0f} ms queued, {:.0f} ms running){}", done.session_id, done.request_id,
                 outcome.report ? "done" : outcome.status.ToString(), outcome.queue_ms, outcome.run_ms,
                 weak.expired() ? "; session gone, result dropped" : "");
    if (auto self = weak.lock()) self->DeliverResult(done.request_id, frame);
    if (outcome.report) hub->Publish(done.robot_id, frame, done.session_id);
  };
}

// ---------------------------------------------------------------- recording

void Session::StartRecording(const pb::HelloReply& reply, const pb::ClientMessage& hello) {
  namespace fs = std::filesystem;
  const auto start_ms = static_cast<long long>(connected_unix_s_ * 1000);
  const fs::path path =
      fs::path(ctx_.config.record_dir) / fmt::format("arref-session-{}-{}.arrec", start_ms, id_);
  std::error_code ec;
  fs::create_directories(ctx_.config.record_dir, ec);
  pb::RecordingHeader header;
  header.set_server_version(ctx_.server_version);
  header.set_protocol_version(wire::kProtocolVersion);
  header.set_session_id(id_);
  header.set_start_unix_s(connected_unix_s_);
  header.set_start_server_time_s(std::chrono::duration<double>(connected_at_.time_since_epoch()).count());
  header.set_client_name(client_name_);
  *header.mutable_robots() = reply.robots();
  header.set_registration_yaml(RegistrationYaml(ctx_.config));
  auto writer = wire::RecordingWriter::Create(path.string(), std::move(header));
  if (!writer.ok()) {
    spdlog::warn("session {}: not recorded: {}", id_, writer.status().ToString());
    return;
  }
  recorder_ = std::move(*writer);
  spdlog::info("session {}: recording to {}", id_, recorder_->path());
  Record(hello);
}

void Session::Record(const pb::ClientMessage& message) {
  if (recorder_) KeepRecording(recorder_->Append(MsSince(connected_at_) / 1000.0, message));
}

void Session::RecordAnswer(std::uint64_t request_id) {
  if (recorder_) KeepRecording(recorder_->AppendAnswer(MsSince(connected_at_) / 1000.0, request_id));
}

void Session::KeepRecording(const Status& written) {
  if (written.ok()) return;
  spdlog::warn("session {}: recording stopped: {}", id_, written.ToString());
  recorder_.reset();
}

// ---------------------------------------------------------------- writing

void Session::SendFrame(std::shared_ptr<const std::string> frame) {
  net::post(transport_->executor(), [self = shared_from_this(), frame = std::move(frame)]() mutable {
    self->Enqueue(std::move(frame));
  });
}

void Session::DeliverResult(std::uint64_t request_id, std::shared_ptr<const std::string> frame) {
  net::post(transport_->executor(), [self = shared_from_this(), request_id, frame = std::move(frame)]() mutable {
    self->in_flight_.erase(request_id);
    self->RecordAnswer(request_id);
    self->Enqueue(std::move(frame));
    if (self->read_closed_ && self->in_flight_.empty())
      self->StartClosing("client closed its side; every result delivered");
  });
}

void Session::NotifyShutdown(double grace_s) {
  net::post(transport_->executor(), [self = shared_from_this(), grace_s] {
    if (self->shutdown_notified_ || self->state_ != State::kReady) return;
    self->shutdown_notified_ = true;
    pb::ServerMessage message;
    message.mutable_shutdown()->set_reason("server shutting down: queued requests are cancelled, running ones finish");
    message.mutable_shutdown()->set_grace_s(grace_s);
    self->Send(message);
  });
}

void Session::CloseGracefully(const std::string& reason) {
  net::post(transport_->executor(), [self = shared_from_this(), reason] { self->StartClosing(reason); });
}

void Session::Send(const pb::ServerMessage& message) { Enqueue(wire::SharedFrame(message)); }

void Session::SendError(pb::ErrorCode code, const std::string& message, std::uint64_t request_id,
                        std::uint64_t surface_id) {
  spdlog::info("session {}: error {}: {}", id_, wire::ErrorCodeName(code), message);
  Send(wire::ErrorMessage(code, message, request_id, surface_id));
}

void Session::Enqueue(std::shared_ptr<const std::string> frame) {
  if (state_ >= State::kClosing || handshaking_) return;
  const auto& limits = ctx_.config.limits;
  if (write_queue_bytes_ + frame->size() > limits.max_send_queue_bytes ||
      write_queue_.size() + 1 > limits.max_send_queue_messages) {
    CloseNow(fmt::format("dropped: {} replies ({} bytes) unsent exceed the send queue limit ({} bytes, {} messages); "
                         "the client is not reading", write_queue_.size(), write_queue_bytes_,
                         limits.max_send_queue_bytes, limits.max_send_queue_messages));
    return;
  }
  write_queue_bytes_ += frame->size();
  write_queue_.push_back(std::move(frame));
  if (!writing_) WriteNext();
}

void Session::WriteNext() {
  if (state_ == State::kClosed) return;
  if (write_queue_.empty()) {
    writing_ = false;
    if (state_ == State::kClosing) FinishClosing();
    return;
  }
  writing_ = true;
  write_timer_.expires_after(Seconds(ctx_.config.send_timeout_s));
  write_timer_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
    if (ec || self->state_ == State::kClosed) return;
    self->CloseNow(fmt::format("dropped: a write stalled for {} s (server.send_timeout_s)",
                               self->ctx_.config.send_timeout_s));
  });
  transport_->AsyncWrite(net::buffer(*write_queue_.front()),
                        [self = shared_from_this()](const boost::system::error_code& ec, std::size_t n) {
                          self->OnWrite(ec, n);
                        });
}

void Session::OnWrite(const boost::system::error_code& ec, std::size_t /*bytes*/) {
  write_timer_.cancel();
  if (state_ == State::kClosed) return;
  if (ec) {
    CloseNow("write failed: " + ec.message());
    return;
  }
  write_queue_bytes_ -= write_queue_.front()->size();
  write_queue_.pop_front();
  WriteNext();
}

// ---------------------------------------------------------------- closing

void Session::FailAndClose(pb::ErrorCode code, const std::string& message) {
  if (state_ >= State::kClosing) return;
  spdlog::warn("session {} ({}): closing: {}: {}", id_, peer_, wire::ErrorCodeName(code), message);
  if (handshaking_) return CloseNow(std::string(wire::ErrorCodeName(code)) + ": " + message);
  Send(wire::ErrorMessage(code, message, 0, 0, /*fatal=*/true));
  StartClosing(std::string(wire::ErrorCodeName(code)) + ": " + message);
}

void Session::StartClosing(const std::string& reason) {
  if (state_ >= State::kClosing) return;
  state_ = State::kClosing;
  close_reason_ = reason;
  idle_timer_.cancel();
  hello_timer_.cancel();
  frame_timer_.cancel();
  transport_->ShutdownReceive();  // ends the pending read
  if (!writing_) return FinishClosing();
  linger_timer_.expires_after(kLinger);
  linger_timer_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
    if (!ec) self->CloseNow(self->close_reason_ + " (unsent replies dropped after linger)");
  });
}

// Every reply written: the connection ends cleanly (TLS: close_notify, sent within
// kCloseNotifyDeadline), then the session closes.
void Session::FinishClosing() {
  if (handshaking_) return CloseNow(close_reason_);  // no TLS session yet to close
  finishing_ = true;
  if (reading_ || transport_closing_) return;  // OnRead comes back here once the read has ended
  transport_closing_ = true;
  linger_timer_.cancel();
  transport_->AsyncCloseNotify(kCloseNotifyDeadline, [self = shared_from_this()] {
    self->CloseNow(self->close_reason_);
  });
}

void Session::CloseNow(const std::string& reason) {
  if (state_ == State::kClosed) return;
  state_ = State::kClosed;
  // Drops are the server's decision (slow or stalled client): worth a warning.
  if (reason.rfind("dropped", 0) == 0)
    spdlog::warn("session {} ({}) closed: {}", id_, peer_, reason);
  else
    spdlog::info("session {} ({}) closed: {}", id_, peer_, reason);
  idle_timer_.cancel();
  hello_timer_.cancel();
  frame_timer_.cancel();
  write_timer_.cancel();
  linger_timer_.cancel();
  transport_->Close();
  write_queue_.clear();
  write_queue_bytes_ = 0;
  frame_memory_.Release();
  spatial_ = SpatialMesh();  // nothing reads the map once closed: free it with its charge
  surface_memory_.clear();
  const auto dropped = ctx_.jobs.CancelSession(id_);  // running ones stop at their next stage
  if (!dropped.empty()) spdlog::info("session {}: {} queued requests dropped with it", id_, dropped.size());
  ctx_.hub.RemoveSession(id_);
  ctx_.tracking.RemoveSession(id_);
  if (ctx_.on_session_closed) ctx_.on_session_closed(id_);
}

}  // namespace arref::server
