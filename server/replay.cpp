#include "replay.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <deque>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <utility>

#include "arref/scene/spatial_mesh.h"
#include "convert.h"
#include "mapping_motion.h"
#include "registration_job.h"
#include "request_builder.h"
#include "subscriber_hub.h"
#include "tracking_messages.h"
#include "tracking_service.h"

namespace arref::server {
namespace {

namespace pb = wire::pb;

// Takes the tracking updates (and frame errors) the TrackingService sends to the session.
class CollectingSink : public TrackingSink {
 public:
  explicit CollectingSink(std::uint64_t id) : id_(id) {}
  std::uint64_t id() const override { return id_; }
  void SendFrame(std::shared_ptr<const std::string> frame) override {
    const auto* data = reinterpret_cast<const std::uint8_t*>(frame->data());
    const wire::FrameHeader h = wire::DecodeFrameHeader(data, frame->size(), frame->size());
    pb::ServerMessage message;
    if (h.state == wire::FrameHeader::State::kComplete &&
        message.ParseFromArray(data + h.header_bytes, static_cast<int>(h.body_bytes)))
      pushed_.push_back(std::move(message));
  }
  std::vector<pb::ServerMessage> Take() { return std::exchange(pushed_, {}); }

 private:
  std::uint64_t id_;
  std::vector<pb::ServerMessage> pushed_;
};

// The recording server's steady clock at t_s after the connection, and that clock as Unix time
// (version 1 recordings, without start_server_time_s, cannot say: 0).
struct RecordedClock {
  explicit RecordedClock(const pb::RecordingHeader& h)
      : known(h.has_start_server_time_s()), start_server_s(h.start_server_time_s()), start_unix_s(h.start_unix_s()) {}
  double ServerTime(double t_s) const { return start_server_s + t_s; }
  double UnixTime(double server_time_s) const { return known ? start_unix_s + (server_time_s - start_server_s) : 0.0; }
  bool known;
  double start_server_s, start_unix_s;
};

// What one recorded session held, as the server's Session held it (without its limits, which
// a recording already passed).
class OfflineSession {
 public:
  OfflineSession(const pb::RecordingHeader& header, RobotRegistry& robots, const RegistrationOptions& registration)
      : header_(header),
        clock_(header),
        robots_(robots),
        registration_(registration),
        sink_(std::make_shared<CollectingSink>(header.session_id())),
        tracking_(hub_, TrackingServiceOptions{.process_inline = true,
                                               .unix_time_of = [this](double t) { return clock_.UnixTime(t); }}) {}

  // The answer to one message, if it has one.
  std::optional<pb::ServerMessage> Handle(const pb::ClientMessage& m, double t_s) {
    using K = pb::ClientMessage::KindCase;
    switch (m.kind_case()) {
      case K::kSurfaceUpsert: return OnSurfaceUpsert(m.surface_upsert());
      case K::kSurfaceRemove:
        if (!spatial_.Remove(m.surface_remove().surface_id()))
          return wire::ErrorMessage(pb::ERROR_CODE_UNKNOWN_SURFACE, "surface is not held by this session", 0,
                                    m.surface_remove().surface_id());
        return std::nullopt;
      case K::kSeedPose: return OnSeedPose(m.seed_pose());
      case K::kJointState: return OnJointState(m.joint_state());
      case K::kRegisterRequest: return OnRegisterRequest(m.register_request(), t_s);
      case K::kSubscribe: return OnSubscribe(m.subscribe());
      case K::kPing: return OnPing(m.ping(), t_s);
      case K::kTrackRequest:
        return Answer(HandleTrackRequest(m.track_request(), robots_, tracking_, sink_, seed_));
      case K::kDepthFrame: return Answer(HandleDepthFrame(m.depth_frame(), tracking_, sink_->id()));
      case K::kClockReport: return Answer(HandleClockReport(m.clock_report(), tracking_, sink_->id()));
      // Hello; Cancel is the replay's, which knows what is in flight.
      default: return std::nullopt;
    }
  }

  // What tracking sent the session since the last call (updates and frame errors, in order).
  std::vector<pb::ServerMessage> TakePushed() { return sink_->Take(); }

  static std::optional<pb::ServerMessage> Answer(const std::optional<Refusal>& refused) {
    if (!refused) return std::nullopt;
    return wire::ErrorMessage(refused->code, refused->message);
  }

 private:
  // Offline there are no other sessions whose results it would see: the answer only.
  std::optional<pb::ServerMessage> OnSubscribe(const pb::Subscribe& m) {
    if (!robots_.Find(m.robot_id()))
      return wire::ErrorMessage(pb::ERROR_CODE_UNKNOWN_ROBOT,
                                fmt::format("Subscribe: robot '{}' is not served here (served: {})", m.robot_id(),
                                            robots_.Ids()));
    pb::ServerMessage reply;
    reply.mutable_subscribed()->set_robot_id(m.robot_id());
    reply.mutable_subscribed()->set_subscribed(!m.unsubscribe());
    return reply;
  }

  // The server's clock is the recording's (for a version 1 recording: seconds after the
  // connection was accepted).
  pb::ServerMessage OnPing(const pb::Ping& m, double t_s) const {
    pb::ServerMessage reply;
    pb::Pong* pong = reply.mutable_pong();
    pong->set_nonce(m.nonce());
    pong->set_payload(m.payload());
    pong->set_client_time_s(m.client_time_s());
    pong->set_receive_time_s(clock_.ServerTime(t_s));
    pong->set_server_time_s(clock_.ServerTime(t_s));
    return reply;
  }

  std::optional<pb::ServerMessage> OnSurfaceUpsert(const pb::SurfaceUpsert& m) {
    auto surface = wire::SurfaceFromProto(m);
    Status s = surface.ok() ? spatial_.Upsert(std::move(*surface)) : surface.status();
    if (!s.ok())
      return wire::ErrorMessage(pb::ERROR_CODE_BAD_SURFACE,
                                fmt::format("surface {} rejected: {}", m.surface_id(), s.message()), 0, m.surface_id());
    return std::nullopt;
  }

  std::optional<pb::ServerMessage> OnSeedPose(const pb::SeedPose& m) {
    const auto frame = wire::FromProto(m.frame());
    if (!frame.ok()) return wire::ErrorMessage(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose: " + frame.status().message());
    auto T = wire::PoseFromProto(m.t_world_seed(), *frame);
    if (!T.ok()) return wire::ErrorMessage(pb::ERROR_CODE_INVALID_ARGUMENT, "SeedPose.T_world_seed: " + T.status().message());
    seed_ = *T;
    seed_frame_ = *frame;
    return std::nullopt;
  }

  // As the live session does (ReadJointState), so that later requests see the same state.
  std::optional<pb::ServerMessage> OnJointState(const pb::JointState& m) {
    JointStateOutcome outcome = ReadJointState(m, robots_);
    std::optional<pb::ServerMessage> answer;
    if (outcome.error != pb::ERROR_CODE_UNSPECIFIED)  // then it was rejected, or names no robot served
      answer = wire::ErrorMessage(outcome.error, outcome.message);
    else if (outcome.keep)
      answer = Answer(FeedJointStream(m, outcome.complete, tracking_, sink_->id()));
    if (outcome.keep && outcome.joints.rejected.empty() && spatial_.size() > 0)
      mapping_motion_.Add(m.robot_id(), outcome.joints.values);  // as the live session records it
    if (outcome.keep) joints_[m.robot_id()] = std::move(outcome.joints);
    return answer;
  }

  std::optional<pb::ServerMessage> OnRegisterRequest(const pb::RegisterRequest& m, double t_s) {
    auto job = BuildJob(m, robots_, registration_,
                        SessionDefaults{.seed = seed_, .seed_frame = seed_frame_, .joints = &joints_});
    if (!job.ok()) return wire::ErrorMessage(RequestErrorCode(job.status()), job.status().message(), m.request_id());
    if (spatial_.size() == 0)
      return wire::ErrorMessage(pb::ERROR_CODE_NO_SCENE,
                                "the session holds no surfaces: send SurfaceUpsert messages first", m.request_id());
    Job& j = **job;
    j.session_id = header_.session_id();
    j.scene_world = spatial_.MergedWorld();
    j.joints_while_mapping = mapping_motion_.For(j.robot_id, robots_.Find(j.robot_id)->model);
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
    AddMappingMotion(j.joints_while_mapping, outcome, result.mutable_result());
    return result;
  }

  const pb::RecordingHeader& header_;
  const RecordedClock clock_;
  RobotRegistry& robots_;
  const RegistrationOptions& registration_;
  std::shared_ptr<CollectingSink> sink_;
  SubscriberHub hub_;  // no other sessions offline: nobody subscribes
  TrackingService tracking_;  // declared last: its updates reach the members above
  SpatialMesh spatial_;
  MappingMotion mapping_motion_;
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

// A session's Results in the order it would send them. A request whose answer the recording
// timed (version 2) is answered then, and a Cancel decided by that time, as the live server
// decided it. Otherwise each request runs when the one before it is done (or when it
// arrives), for as long as it took offline, and a Cancel that arrives before that run is over
// answers it CANCELLED (whether the live server did depends on how long the run took there).
class PendingResults {
 public:
  PendingResults(const std::map<std::uint64_t, double>& answered_at_s,
                 std::function<void(std::size_t, double, pb::ServerMessage)> emit)
      : answered_at_s_(answered_at_s), emit_(std::move(emit)) {}

  void Add(std::size_t index, double t_s, pb::ServerMessage result) {
    const double run_s = result.result().server_ms() / 1000.0;
    const auto answered = answered_at_s_.find(result.result().request_id());
    std::optional<double> recorded;
    if (answered != answered_at_s_.end()) recorded = std::max(answered->second, t_s);
    pending_.push_back({index, t_s, run_s, 0.0, recorded, std::move(result)});
    Reschedule();
  }

  // Answers every result done by t_s, in the order they were done.
  void Until(double t_s) {
    for (;;) {
      auto next = std::min_element(pending_.begin(), pending_.end(),
                                   [](const Pending& a, const Pending& b) { return a.done_s < b.done_s; });
      if (next == pending_.end() || next->done_s > t_s) return;
      if (!next->recorded_done_s) free_at_s_ = next->done_s;
      emit_(next->index, next->t_s, std::move(next->message));
      pending_.erase(next);
    }
  }

  // The Cancel of a request arriving at t_s: its error, if the live server would have answered one.
  std::optional<pb::ServerMessage> Cancel(std::uint64_t request_id, double t_s) {
    if (request_id == 0)
      return wire::ErrorMessage(pb::ERROR_CODE_INVALID_ARGUMENT,
                                "Cancel.request_id must be >= 1 (0 is never a request id)");
    Until(t_s);
    auto it = std::find_if(pending_.begin(), pending_.end(),
                           [&](const Pending& p) { return p.message.result().request_id() == request_id; });
    if (it == pending_.end())
      return wire::ErrorMessage(
          pb::ERROR_CODE_UNKNOWN_REQUEST,
          fmt::format("request {} is not in flight (never accepted or already answered)", request_id), request_id);
    const double started_s = it->done_s - it->run_s;
    const bool queued = !it->recorded_done_s && t_s < started_s;
    const std::string why =
        it->recorded_done_s
            ? fmt::format("cancelled by the client (replay: the Cancel came {:.3f} s after the request, before the "
                          "live server answered it at {:.3f} s)",
                          t_s - it->t_s, *it->recorded_done_s - it->t_s)
            : fmt::format("cancelled by the client while {} (replay: the Cancel came {:.3f} s after the request, the "
                          "replayed run took {:.3f} s)",
                          queued ? "queued" : "running", t_s - it->t_s, it->run_s);
    const pb::Result& ran = it->message.result();
    const wire::ResultHeader header{.request_id = ran.request_id(), .robot_id = ran.robot_id(),
                                    .session_id = ran.session_id(), .queue_ms = 0.0,
                                    .server_ms = 1000.0 * (t_s - it->t_s),
                                    .scene_time_unix_s = ran.scene_time_unix_s(),
                                    .scene_headset_time_s = ran.scene_headset_time_s()};
    const auto frame = wire::FromProto(ran.frame());
    it->message = wire::ResultMessage(header, std::nullopt, Status::Cancelled(why),
                                      frame.ok() ? *frame : FrameConvention::kRos);
    if (!it->recorded_done_s) it->run_s = queued ? 0.0 : t_s - started_s;
    Reschedule();
    return std::nullopt;
  }

 private:
  struct Pending {
    std::size_t index;
    double t_s, run_s, done_s;
    std::optional<double> recorded_done_s;  // when the live server answered it
    pb::ServerMessage message;
  };
  // Requests without a recorded answer run one after the other on the replay's one worker.
  void Reschedule() {
    double free_s = free_at_s_;
    for (Pending& p : pending_)
      if (p.recorded_done_s)
        p.done_s = *p.recorded_done_s;
      else
        free_s = p.done_s = std::max(p.t_s, free_s) + p.run_s;
  }
  const std::map<std::uint64_t, double>& answered_at_s_;
  std::function<void(std::size_t, double, pb::ServerMessage)> emit_;
  std::deque<Pending> pending_;
  double free_at_s_ = 0.0;
};

// A tracked robot whose joint stream came on another connection (a robot-side program) is
// posed at its zero joints offline: the replay says so rather than let the updates mislead.
class JointStreamCheck {
 public:
  void See(const pb::ClientMessage& m) {
    if (m.has_track_request() && !m.track_request().stop()) tracked_.insert(m.track_request().robot_id());
    if (m.has_joint_state() && m.joint_state().timestamp_s() > 0) streamed_.insert(m.joint_state().robot_id());
  }
  void WarnIfMissing() const {
    for (const std::string& id : tracked_)
      if (!streamed_.count(id))
        spdlog::warn("replay: robot '{}' was tracked but this recording holds no timestamped JointState for it (its "
                     "joint stream came on another connection?): it was tracked at its zero joints here",
                     id);
  }

 private:
  std::set<std::string> tracked_, streamed_;
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
  PendingResults results(recording.answered_at_s, emit);
  JointStreamCheck joint_streams;
  for (std::size_t i = 0; i < recording.messages.size(); ++i) {
    const auto& recorded = recording.messages[i];
    results.Until(recorded.t_s());
    joint_streams.See(recorded.message());
    std::optional<pb::ServerMessage> answer =
        recorded.message().has_cancel() ? results.Cancel(recorded.message().cancel().request_id(), recorded.t_s())
                                        : session.Handle(recorded.message(), recorded.t_s());
    if (answer && answer->has_result())
      results.Add(i, recorded.t_s(), std::move(*answer));
    else if (answer)
      emit(i, recorded.t_s(), std::move(*answer));
    for (pb::ServerMessage& pushed : session.TakePushed()) emit(i, recorded.t_s(), std::move(pushed));
  }
  results.Until(std::numeric_limits<double>::infinity());
  joint_streams.WarnIfMissing();
  return answers;
}

}  // namespace arref::server
