#include "replay.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <deque>
#include <limits>
#include <map>
#include <optional>

#include "arref/scene/spatial_mesh.h"
#include "convert.h"
#include "registration_job.h"
#include "request_builder.h"

namespace arref::server {
namespace {

namespace pb = wire::pb;

// What one recorded session held, as the server's Session held it (without its limits, which
// a recording already passed).
class OfflineSession {
 public:
  OfflineSession(const pb::RecordingHeader& header, RobotRegistry& robots, const RegistrationOptions& registration)
      : header_(header), robots_(robots), registration_(registration) {}

  // The answer to one message, if it has one.
  std::optional<pb::ServerMessage> Handle(const pb::ClientMessage& m, double t_s) {
    using K = pb::ClientMessage::KindCase;
    switch (m.kind_case()) {
      case K::kSurfaceUpsert: return OnSurfaceUpsert(m.surface_upsert());
      case K::kSurfaceRemove:
        if (!spatial_.Remove(m.surface_remove().surface_id()))
          return Error(pb::ERROR_CODE_UNKNOWN_SURFACE, "surface is not held by this session", 0,
                       m.surface_remove().surface_id());
        return std::nullopt;
      case K::kSeedPose: return OnSeedPose(m.seed_pose());
      case K::kJointState: return OnJointState(m.joint_state());
      case K::kRegisterRequest: return OnRegisterRequest(m.register_request(), t_s);
      case K::kSubscribe: return OnSubscribe(m.subscribe());
      case K::kPing: return OnPing(m.ping(), t_s);
      // Hello; tracking (TrackRequest, DepthFrame, ClockReport) is not re-run offline; Cancel is
      // the replay's, which knows what is in flight.
      default: return std::nullopt;
    }
  }

  static pb::ServerMessage Error(pb::ErrorCode code, const std::string& message, std::uint64_t request_id = 0,
                                 std::uint64_t surface_id = 0) {
    pb::ServerMessage reply;
    auto* e = reply.mutable_error();
    e->set_code(code);
    e->set_message(message);
    e->set_request_id(request_id);
    e->set_surface_id(surface_id);
    return reply;
  }

 private:
  // Offline there are no other sessions whose results it would see: the answer only.
  std::optional<pb::ServerMessage> OnSubscribe(const pb::Subscribe& m) {
    if (!robots_.Find(m.robot_id()))
      return Error(pb::ERROR_CODE_UNKNOWN_ROBOT,
                   fmt::format("Subscribe: robot '{}' is not served here (served: {})", m.robot_id(), robots_.Ids()));
    pb::ServerMessage reply;
    reply.mutable_subscribed()->set_robot_id(m.robot_id());
    reply.mutable_subscribed()->set_subscribed(!m.unsubscribe());
    return reply;
  }

  // The server's clock is the recording's: seconds after the connection was accepted.
  static pb::ServerMessage OnPing(const pb::Ping& m, double t_s) {
    pb::ServerMessage reply;
    pb::Pong* pong = reply.mutable_pong();
    pong->set_nonce(m.nonce());
    pong->set_payload(m.payload());
    pong->set_client_time_s(m.client_time_s());
    pong->set_receive_time_s(t_s);
    pong->set_server_time_s(t_s);
    return reply;
  }

  std::optional<pb::ServerMessage> OnSurfaceUpsert(const pb::SurfaceUpsert& m) {
    auto surface = wire::SurfaceFromProto(m);
    Status s = surface.ok() ? spatial_.Upsert(std::move(*surface)) : surface.status();
    if (!s.ok())
      return Error(pb::ERROR_CODE_BAD_SURFACE, fmt::format("surface {} rejected: {}", m.surface_id(), s.message()), 0,
                   m.surface_id());
    return std::nullopt;
  }

  std::optional<pb::ServerMessage> OnSeedPose(const pb::SeedPose& m) {
    const auto frame = wire::FromProto(m.frame());
    if (!frame.ok()) return Error(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose: " + frame.status().message());
    auto T = wire::PoseFromProto(m.t_world_seed(), *frame);
    if (!T.ok()) return Error(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose.T_world_seed: " + T.status().message());
    seed_ = *T;
    seed_frame_ = *frame;
    return std::nullopt;
  }

  // As the live session does (ReadJointState), so that later requests see the same state.
  std::optional<pb::ServerMessage> OnJointState(const pb::JointState& m) {
    JointStateOutcome outcome = ReadJointState(m, robots_);
    if (outcome.keep) joints_[m.robot_id()] = std::move(outcome.joints);
    if (outcome.error != pb::ERROR_CODE_UNSPECIFIED) return Error(outcome.error, outcome.message);
    return std::nullopt;
  }

  std::optional<pb::ServerMessage> OnRegisterRequest(const pb::RegisterRequest& m, double t_s) {
    auto job = BuildJob(m, robots_, registration_,
                        SessionDefaults{.seed = seed_, .seed_frame = seed_frame_, .joints = &joints_});
    if (!job.ok()) return Error(RequestErrorCode(job.status()), job.status().message(), m.request_id());
    if (spatial_.size() == 0)
      return Error(pb::ERROR_CODE_NO_SCENE, "the session holds no surfaces: send SurfaceUpsert messages first",
                   m.request_id());
    Job& j = **job;
    j.session_id = header_.session_id();
    j.scene_world = spatial_.MergedWorld();
    j.scene_time_unix_s = header_.start_unix_s() + t_s;  // as the server stamped it, to the recording's precision
    for (const auto& [sid, surface] : spatial_.surfaces())
      j.scene_headset_time_s = std::max(j.scene_headset_time_s, surface.timestamp_s);
    const JobOutcome outcome = RunRegistrationJob(j, robots_);
    const wire::ResultHeader result_header{.request_id = j.request_id, .robot_id = j.robot_id,
                                           .session_id = j.session_id, .queue_ms = 0.0,
                                           .server_ms = outcome.run_ms, .scene_time_unix_s = j.scene_time_unix_s,
                                           .scene_headset_time_s = j.scene_headset_time_s};
    pb::ServerMessage result = wire::ResultMessage(result_header, outcome.report, outcome.status, j.result_frame);
    if (outcome.seedless)  // as the live session answers it
      wire::FillCandidates(outcome.instances, outcome.primary, j.result_frame, result.mutable_result());
    return result;
  }

  const pb::RecordingHeader& header_;
  RobotRegistry& robots_;
  const RegistrationOptions& registration_;
  SpatialMesh spatial_;
  std::optional<Iso3> seed_;
  FrameConvention seed_frame_ = FrameConvention::kUnity;
  std::map<std::string, SessionJoints> joints_;
};

// The registration defaults to replay with: the recording's, or the config's.
Result<ServerConfig> RegistrationConfig(const wire::Recording& recording, const ServerConfig& config,
                                        const ReplayOptions& options) {
  if (!options.recorded_registration || recording.header.registration_yaml().empty()) return config;
  auto recorded = ParseServerConfig(recording.header.registration_yaml(), ".");
  if (!recorded.ok()) return recorded.status().WithContext("the recording's registration settings");
  return recorded;
}

// A session's Results in the order it would send them: each request runs when the one before it
// is done (or when it arrives), for as long as it took offline. A Cancel that arrives before its
// request's run is over answers it CANCELLED instead, as the live server would have (whether
// it did depends on how long the run took there; the recording does not say).
class PendingResults {
 public:
  explicit PendingResults(std::function<void(std::size_t, double, pb::ServerMessage)> emit) : emit_(std::move(emit)) {}

  void Add(std::size_t index, double t_s, pb::ServerMessage result) {
    const double run_s = result.result().server_ms() / 1000.0;
    pending_.push_back({index, t_s, run_s, 0.0, std::move(result)});
    Reschedule();
  }

  // Answers every result done by t_s.
  void Until(double t_s) {
    while (!pending_.empty() && pending_.front().done_s <= t_s) {
      free_at_s_ = pending_.front().done_s;
      emit_(pending_.front().index, pending_.front().t_s, std::move(pending_.front().message));
      pending_.pop_front();
    }
  }

  // The Cancel of a request arriving at t_s: its error, if the live server would have answered one.
  std::optional<pb::ServerMessage> Cancel(std::uint64_t request_id, double t_s) {
    if (request_id == 0)
      return OfflineSession::Error(pb::ERROR_CODE_INVALID_ARGUMENT,
                                   "Cancel.request_id must be >= 1 (0 is never a request id)");
    Until(t_s);
    auto it = std::find_if(pending_.begin(), pending_.end(),
                           [&](const Pending& p) { return p.message.result().request_id() == request_id; });
    if (it == pending_.end())
      return OfflineSession::Error(
          pb::ERROR_CODE_UNKNOWN_REQUEST,
          fmt::format("request {} is not in flight (never accepted or already answered)", request_id), request_id);
    const double started_s = it->done_s - it->run_s;
    const bool queued = t_s < started_s;
    const pb::Result& ran = it->message.result();
    const wire::ResultHeader header{.request_id = ran.request_id(), .robot_id = ran.robot_id(),
                                    .session_id = ran.session_id(), .queue_ms = 0.0,
                                    .server_ms = 1000.0 * (t_s - it->t_s),
                                    .scene_time_unix_s = ran.scene_time_unix_s(),
                                    .scene_headset_time_s = ran.scene_headset_time_s()};
    const auto frame = wire::FromProto(ran.frame());
    it->message = wire::ResultMessage(
        header, std::nullopt,
        Status::Cancelled(fmt::format("cancelled by the client while {} (replay: the Cancel came {:.3f} s after the "
                                      "request, the replayed run took {:.3f} s)",
                                      queued ? "queued" : "running", t_s - it->t_s, it->run_s)),
        frame.ok() ? *frame : FrameConvention::kRos);
    it->run_s = queued ? 0.0 : t_s - started_s;
    Reschedule();
    return std::nullopt;
  }

 private:
  struct Pending {
    std::size_t index;
    double t_s, run_s, done_s;
    pb::ServerMessage message;
  };
  void Reschedule() {
    double free_s = free_at_s_;
    for (Pending& p : pending_) free_s = p.done_s = std::max(p.t_s, free_s) + p.run_s;
  }
  std::function<void(std::size_t, double, pb::ServerMessage)> emit_;
  std::deque<Pending> pending_;
  double free_at_s_ = 0.0;
};

}  // namespace

Result<std::vector<ReplayedAnswer>> ReplayRecording(const wire::Recording& recording, const ServerConfig& config,
                                                    const ReplayOptions& options,
                                                    const std::function<void(const ReplayedAnswer&)>& on_answer) {
  ARREF_ASSIGN_OR_RETURN(const ServerConfig registration, RegistrationConfig(recording, config, options));
  ARREF_ASSIGN_OR_RETURN(auto robots, RobotRegistry::Load(config.robots, registration.model_cache_entries));
  for (const auto& info : recording.header.robots()) {
    const ServedRobot* robot = robots->Find(info.id());
    if (!robot)
      spdlog::warn("replay: the recording's robot '{}' is not in the config (has: {}); its requests will fail",
                   info.id(), robots->Ids());
    else if (robot->model.name() != info.name())
      spdlog::warn("replay: robot '{}' is URDF robot '{}' here but was '{}' when recorded", info.id(),
                   robot->model.name(), info.name());
  }
  OfflineSession session(recording.header, *robots, registration.registration);
  std::vector<ReplayedAnswer> answers;
  const auto emit = [&](std::size_t index, double t_s, pb::ServerMessage message) {
    answers.push_back({.message_index = index, .t_s = t_s, .message = std::move(message)});
    if (on_answer) on_answer(answers.back());
  };
  PendingResults results(emit);
  for (std::size_t i = 0; i < recording.messages.size(); ++i) {
    const auto& recorded = recording.messages[i];
    results.Until(recorded.t_s());
    std::optional<pb::ServerMessage> answer =
        recorded.message().has_cancel() ? results.Cancel(recorded.message().cancel().request_id(), recorded.t_s())
                                        : session.Handle(recorded.message(), recorded.t_s());
    if (!answer) continue;
    if (answer->has_result())
      results.Add(i, recorded.t_s(), std::move(*answer));
    else
      emit(i, recorded.t_s(), std::move(*answer));
  }
  results.Until(std::numeric_limits<double>::infinity());
  return answers;
}

}  // namespace arref::server
