#include "session.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>

#include "arref/base/clock.h"
#include "convert.h"
#include "request_builder.h"

namespace arref::server {
namespace {

namespace pb = wire::pb;

constexpr std::size_t kReadChunk = 64 * 1024;
constexpr std::size_t kMaxPingPayload = 64 * 1024;
constexpr double kJointMotionWhileMappingRad = 0.02;  // a joint moving more smears the arm's mesh
constexpr auto kLinger = std::chrono::seconds(2);  // time to flush a final error before closing

std::chrono::milliseconds Seconds(double s) { return std::chrono::milliseconds(static_cast<long long>(s * 1000)); }

}  // namespace

// ---------------------------------------------------------------- Session: life cycle

Session::Session(tcp::socket socket, ServerContext& context, std::uint64_t id)
    : socket_(std::move(socket)),
      ctx_(context),
      id_(id),
      rx_(context.config.limits.max_message_bytes, 4 * kReadChunk),
      idle_timer_(socket_.get_executor()),
      write_timer_(socket_.get_executor()),
      linger_timer_(socket_.get_executor()) {
  boost::system::error_code ec;
  const auto endpoint = socket_.remote_endpoint(ec);
  peer_ = ec ? "?" : endpoint.address().to_string() + ":" + std::to_string(endpoint.port());
}

Session::~Session() { spdlog::debug("session {} destroyed", id_); }

void Session::Start() {
  net::dispatch(socket_.get_executor(), [self = shared_from_this()] {
    spdlog::info("session {}: connected from {}", self->id_, self->peer_);
    self->ArmIdleTimer();
    self->ReadMore();
  });
}

void Session::Reject(pb::ErrorCode code, const std::string& message) {
  net::dispatch(socket_.get_executor(), [self = shared_from_this(), code, message] {
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

// ---------------------------------------------------------------- reading

void Session::ReadMore() {
  if (state_ >= State::kClosing) return;
  const auto space = rx_.Buffer(kReadChunk);
  socket_.async_read_some(net::buffer(space.data(), space.size()),
                          [self = shared_from_this()](const boost::system::error_code& ec, std::size_t n) {
                            self->OnRead(ec, n);
                          });
}

void Session::OnRead(const boost::system::error_code& ec, std::size_t bytes) {
  if (state_ >= State::kClosing) return;
  if (ec) {
    CloseNow(ec == net::error::eof ? "client closed the connection" : "read failed: " + ec.message());
    return;
  }
  rx_.Commit(bytes);
  ArmIdleTimer();
  if (ProcessFrames()) ReadMore();
}

bool Session::ProcessFrames() {
  using Kind = wire::FrameDecoder::Frame::Kind;
  while (state_ < State::kClosing) {
    const wire::FrameDecoder::Frame f = rx_.Next();
    if (f.kind == Kind::kNeedMore) break;
    if (f.kind == Kind::kTooLarge) {
      FailAndClose(pb::ERROR_CODE_MESSAGE_TOO_LARGE,
                   fmt::format("message of {} bytes exceeds the limit of {} bytes (limits.max_message_bytes)",
                               f.body_bytes, ctx_.config.limits.max_message_bytes));
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
    Handle(message);
  }
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
  state_ = State::kReady;
  client_name_ = m.client_name();
  spdlog::info("session {}: hello from '{}' ({})", id_, client_name_, peer_);
  pb::ServerMessage reply;
  auto* r = reply.mutable_hello_reply();
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
  Send(reply);
  if (ctx_.shutting_down) NotifyShutdown(ctx_.config.shutdown_grace_s);
}

void Session::OnSurfaceUpsert(const pb::SurfaceUpsert& m) {
  const std::uint64_t sid = m.surface_id();
  auto surface = wire::SurfaceFromProto(m);
  if (!surface.ok()) {
    SendError(pb::ERROR_CODE_BAD_SURFACE, fmt::format("surface {} rejected: {}", sid, surface.status().message()), 0,
              sid);
    return;
  }
  const auto& limits = ctx_.config.limits;
  const auto old = spatial_.surfaces().find(sid);
  const bool replaces = old != spatial_.surfaces().end();
  const std::size_t surfaces_after = spatial_.size() + (replaces ? 0 : 1);
  const std::size_t vertices_after =
      spatial_.vertex_count() - (replaces ? old->second.mesh.vertices.size() : 0) + surface->mesh.vertices.size();
  if (surfaces_after > limits.max_surfaces_per_session) {
    SendError(pb::ERROR_CODE_LIMIT_EXCEEDED,
              fmt::format("surface {} rejected: the session would hold {} surfaces, limit {} "
                          "(limits.max_surfaces_per_session)", sid, surfaces_after, limits.max_surfaces_per_session),
              0, sid);
    return;
  }
  if (vertices_after > limits.max_vertices_per_session) {
    SendError(pb::ERROR_CODE_LIMIT_EXCEEDED,
              fmt::format("surface {} rejected: the session would hold {} vertices, limit {} "
                          "(limits.max_vertices_per_session)", sid, vertices_after, limits.max_vertices_per_session),
              0, sid);
    return;
  }
  if (Status s = spatial_.Upsert(std::move(*surface)); !s.ok())
    SendError(pb::ERROR_CODE_BAD_SURFACE, fmt::format("surface {} rejected: {}", sid, s.message()), 0, sid);
}

void Session::OnSurfaceRemove(const pb::SurfaceRemove& m) {
  if (!spatial_.Remove(m.surface_id()))
    SendError(pb::ERROR_CODE_UNKNOWN_SURFACE, fmt::format("surface {} is not held by this session", m.surface_id()), 0,
              m.surface_id());
}

void Session::OnSeedPose(const pb::SeedPose& m) {
  const auto frame = wire::FromProto(m.frame());
  if (!frame.ok()) return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose: " + frame.status().message());
  auto T = wire::PoseFromProto(m.t_world_seed(), *frame);
  if (!T.ok()) return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose.T_world_seed: " + T.status().message());
  seed_ = *T;
  seed_frame_ = *frame;
}

void Session::OnJointState(const pb::JointState& m) {
  auto joints = wire::JointsFromProto(m);
  if (!joints.ok()) return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "JointState: " + joints.status().message());
  if (!m.robot_id().empty()) {
    const ServedRobot* robot = ctx_.robots.Find(m.robot_id());
    if (!robot)
      return SendError(pb::ERROR_CODE_UNKNOWN_ROBOT, fmt::format("JointState: robot '{}' is not served here (served: {})",
                                                                 m.robot_id(), ctx_.robots.Ids()));
    if (auto checked = ctx_.robots.ResolveJoints(*robot, *joints); !checked.ok())
      return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "JointState: " + checked.status().message());
  }
  // A timestamped state naming its robot is also a sample of that robot's joint stream.
  if (!m.robot_id().empty() && m.timestamp_s() > 0) {
    const ServedRobot* robot = ctx_.robots.Find(m.robot_id());
    auto complete = ctx_.robots.ResolveJoints(*robot, *joints);
    if (complete.ok())
      if (auto st = ctx_.tracking.AddJoints(m.robot_id(), id_, m.timestamp_s(), *complete); !st.ok())
        SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "JointState: " + st.message());
  }
  if (spatial_.size() > 0)
    for (const auto& [name, value] : *joints) {
      auto [it, fresh] = joint_range_[m.robot_id()].try_emplace(name, value, value);
      if (!fresh) it->second = {std::min(it->second.first, value), std::max(it->second.second, value)};
    }
  joints_[m.robot_id()] = std::move(*joints);
}

double Session::JointMotionWhileMapping(const std::string& robot_id) const {
  double most = 0.0;
  for (const std::string& id : {robot_id, std::string()}) {
    const auto it = joint_range_.find(id);
    if (it == joint_range_.end()) continue;
    for (const auto& [name, range] : it->second) most = std::max(most, range.second - range.first);
  }
  return most;
}

void Session::OnTrackRequest(const pb::TrackRequest& m) {
  const ServedRobot* robot = ctx_.robots.Find(m.robot_id());
  if (!robot)
    return SendError(pb::ERROR_CODE_UNKNOWN_ROBOT, fmt::format("TrackRequest: robot '{}' is not served here (served: {})",
                                                               m.robot_id(), ctx_.robots.Ids()));
  if (m.stop()) return ctx_.tracking.Stop(m.robot_id(), id_);
  const auto result_frame = wire::FromProto(m.result_frame());
  if (!result_frame.ok())
    return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "TrackRequest.result_frame: " + result_frame.status().message());
  std::optional<Iso3> seed = seed_;
  if (m.has_seed()) {
    const auto frame = wire::FromProto(m.seed().frame());
    if (!frame.ok()) return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "TrackRequest.seed: " + frame.status().message());
    auto T = wire::PoseFromProto(m.seed().t_world_seed(), *frame);
    if (!T.ok()) return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "TrackRequest.seed: " + T.status().message());
    seed = *T;
  }
  if (!seed) return SendError(pb::ERROR_CODE_NO_SEED, "TrackRequest: no seed in the request and no SeedPose in the session");
  if (auto st = ctx_.tracking.Start(*robot, m.robot_id(), shared_from_this(), *seed, *result_frame); !st.ok())
    return SendError(wire::ErrorCodeFor(st), "TrackRequest: " + st.message());
}

void Session::OnDepthFrame(const pb::DepthFrame& m) {
  auto frame = wire::DepthFrameFromProto(m);
  if (!frame.ok()) return SendError(pb::ERROR_CODE_BAD_DEPTH_FRAME, fmt::format("DepthFrame {}: {}", m.frame_id(), frame.status().message()));
  if (auto st = ctx_.tracking.SubmitFrame(m.robot_id(), id_, m.frame_id(), std::move(*frame)); !st.ok())
    return SendError(pb::ERROR_CODE_NOT_TRACKING, st.message());
}

void Session::OnClockReport(const pb::ClockReport& m) {
  if (!std::isfinite(m.offset_s()) || !std::isfinite(m.uncertainty_s()) || m.uncertainty_s() < 0)
    return SendError(pb::ERROR_CODE_INVALID_ARGUMENT, "ClockReport: offset and uncertainty must be finite, uncertainty >= 0");
  ctx_.tracking.ReportClock(id_, {m.offset_s(), m.uncertainty_s(), true});
}

void Session::OnCancel(const pb::Cancel& m) {
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
  std::size_t position = 0;
  switch (ctx_.jobs.Submit(job, &position)) {
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
  spdlog::info("session {}: request {} accepted for robot '{}' at queue position {}", id_, rid, m.robot_id(), position);
  pb::ServerMessage reply;
  reply.mutable_accepted()->set_request_id(rid);
  reply.mutable_accepted()->set_queue_position(static_cast<std::uint32_t>(position));
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
  (*job)->session_id = id_;
  (*job)->scene_world = spatial_.MergedWorld();
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
  const double joint_motion = JointMotionWhileMapping(job.robot_id);
  job.on_done = [weak, hub, joint_motion](const Job& done, const JobOutcome& outcome) {
    const wire::ResultHeader header{.request_id = done.request_id,
                                    .robot_id = done.robot_id,
                                    .session_id = done.session_id,
                                    .queue_ms = outcome.queue_ms,
                                    .server_ms = MsSince(done.accepted_at)};
    pb::ServerMessage message = wire::ResultMessage(header, outcome.report, outcome.status, done.result_frame);
    if (joint_motion > kJointMotionWhileMappingRad) {
      pb::Result* r = message.mutable_result();
      r->set_joints_moved_while_mapping(true);
      r->set_joint_motion_rad(joint_motion);
      r->set_message(r->message() + (r->message().empty() ? "" : "; ") +
                     fmt::format("the joints moved by up to {:.2f} rad while the map was made: the arm's mesh is "
                                 "smeared (TrackRequest with depth frames follows a moving robot)", joint_motion));
    }
    const auto frame = wire::SharedFrame(message);
    spdlog::info("session {}: request {} {} ({:.0f} ms queued, {:.0f} ms running){}", done.session_id, done.request_id,
                 outcome.report ? "done" : outcome.status.ToString(), outcome.queue_ms, outcome.run_ms,
                 weak.expired() ? "; session gone, result dropped" : "");
    if (auto self = weak.lock()) self->DeliverResult(done.request_id, frame);
    if (outcome.report) hub->Publish(done.robot_id, frame, done.session_id);
  };
}

// ---------------------------------------------------------------- writing

void Session::SendFrame(std::shared_ptr<const std::string> frame) {
  net::post(socket_.get_executor(), [self = shared_from_this(), frame = std::move(frame)]() mutable {
    self->Enqueue(std::move(frame));
  });
}

void Session::DeliverResult(std::uint64_t request_id, std::shared_ptr<const std::string> frame) {
  net::post(socket_.get_executor(), [self = shared_from_this(), request_id, frame = std::move(frame)]() mutable {
    self->in_flight_.erase(request_id);
    self->Enqueue(std::move(frame));
  });
}

void Session::NotifyShutdown(double grace_s) {
  net::post(socket_.get_executor(), [self = shared_from_this(), grace_s] {
    if (self->shutdown_notified_ || self->state_ != State::kReady) return;
    self->shutdown_notified_ = true;
    pb::ServerMessage message;
    message.mutable_shutdown()->set_reason("server shutting down: queued requests are cancelled, running ones finish");
    message.mutable_shutdown()->set_grace_s(grace_s);
    self->Send(message);
  });
}

void Session::CloseGracefully(const std::string& reason) {
  net::post(socket_.get_executor(), [self = shared_from_this(), reason] { self->StartClosing(reason); });
}

void Session::Send(const pb::ServerMessage& message) { Enqueue(wire::SharedFrame(message)); }

void Session::SendError(pb::ErrorCode code, const std::string& message, std::uint64_t request_id,
                        std::uint64_t surface_id) {
  spdlog::info("session {}: error {}: {}", id_, wire::ErrorCodeName(code), message);
  pb::ServerMessage reply;
  auto* e = reply.mutable_error();
  e->set_code(code);
  e->set_message(message);
  e->set_request_id(request_id);
  e->set_surface_id(surface_id);
  Send(reply);
}

void Session::Enqueue(std::shared_ptr<const std::string> frame) {
  if (state_ >= State::kClosing) return;
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
    if (state_ == State::kClosing) CloseNow(close_reason_);
    return;
  }
  writing_ = true;
  write_timer_.expires_after(Seconds(ctx_.config.send_timeout_s));
  write_timer_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
    if (ec || self->state_ == State::kClosed) return;
    self->CloseNow(fmt::format("dropped: a write stalled for {} s (server.send_timeout_s)",
                               self->ctx_.config.send_timeout_s));
  });
  net::async_write(socket_, net::buffer(*write_queue_.front()),
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
  pb::ServerMessage reply;
  auto* e = reply.mutable_error();
  e->set_code(code);
  e->set_message(message);
  e->set_fatal(true);
  Send(reply);
  StartClosing(std::string(wire::ErrorCodeName(code)) + ": " + message);
}

void Session::StartClosing(const std::string& reason) {
  if (state_ >= State::kClosing) return;
  state_ = State::kClosing;
  close_reason_ = reason;
  idle_timer_.cancel();
  boost::system::error_code ignored;
  socket_.shutdown(tcp::socket::shutdown_receive, ignored);  // ends the pending read
  if (!writing_) return CloseNow(reason);
  linger_timer_.expires_after(kLinger);
  linger_timer_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
    if (!ec) self->CloseNow(self->close_reason_ + " (unsent replies dropped after linger)");
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
  write_timer_.cancel();
  linger_timer_.cancel();
  boost::system::error_code ignored;
  socket_.shutdown(tcp::socket::shutdown_both, ignored);
  socket_.close(ignored);
  write_queue_.clear();
  write_queue_bytes_ = 0;
  const auto dropped = ctx_.jobs.CancelSession(id_);  // running ones stop at their next stage
  if (!dropped.empty()) spdlog::info("session {}: {} queued requests dropped with it", id_, dropped.size());
  ctx_.hub.RemoveSession(id_);
  ctx_.tracking.RemoveSession(id_);
  if (ctx_.on_session_closed) ctx_.on_session_closed(id_);
}

}  // namespace arref::server
