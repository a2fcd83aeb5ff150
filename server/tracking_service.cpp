#include "tracking_service.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>

#include "arref/base/clock.h"
#include "convert.h"
#include "robot_registry.h"
#include "subscriber_hub.h"

namespace arref::server {

namespace pb = wire::pb;

struct TrackingService::Pending {
  DepthFrame frame;  // time on the server's clock
  std::uint64_t frame_id = 0;
  SteadyClock::time_point received;
  ClockEstimate clock;
};

struct TrackingService::Track {
  std::string robot_id;
  std::shared_ptr<const RobotModel> robot;  // the served model, not owned (aliasing pointer)
  std::mutex mu;
  std::condition_variable wake;
  bool stopping = false;
  std::weak_ptr<TrackingSink> owner;
  std::uint64_t owner_id = 0;
  FrameConvention result_frame = FrameConvention::kRos;
  std::mutex tracker_mu;  // held while the tracker runs or is seeded
  std::optional<Tracker> tracker;
  JointHistory history;
  std::optional<Pending> slot;
  std::uint64_t processed = 0, dropped = 0, joints_out_of_order = 0;
  std::thread worker;
  explicit Track(std::vector<std::string> joint_names) : history(std::move(joint_names)) {}
};

TrackingService::TrackingService(SubscriberHub& hub, TrackingServiceOptions options)
    : hub_(hub), options_(std::move(options)) {
  if (!options_.unix_time_of) options_.unix_time_of = &TrackingService::UnixTimeOf;
}

TrackingService::~TrackingService() { Shutdown(); }

void TrackingService::Shutdown() {
  std::map<std::string, std::unique_ptr<Track>> tracks;
  {
    std::lock_guard lock(mu_);
    tracks.swap(tracks_);
  }
  for (auto& [id, t] : tracks) {
    {
      std::lock_guard lock(t->mu);
      t->stopping = true;
    }
    t->wake.notify_all();
    if (t->worker.joinable()) t->worker.join();
  }
}

double TrackingService::Now() {
  return std::chrono::duration<double>(SteadyClock::now().time_since_epoch()).count();
}

double TrackingService::UnixTimeOf(double server_time_s) {
  const double unix_now = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  return unix_now - (Now() - server_time_s);
}

ClockEstimate TrackingService::ClockOf(std::uint64_t session_id) {
  std::lock_guard lock(mu_);
  auto it = clocks_.find(session_id);
  return it == clocks_.end() ? ClockEstimate{} : it->second;
}

void TrackingService::ReportClock(std::uint64_t session_id, const ClockEstimate& clock) {
  std::lock_guard lock(mu_);
  clocks_[session_id] = clock;
}

Status TrackingService::Start(const ServedRobot& served, const std::string& robot_id,
                              const std::shared_ptr<TrackingSink>& session, const Iso3& T_world_base_seed,
                              FrameConvention result_frame, double camera_pose_latency_s) {
  std::lock_guard lock(mu_);
  auto& slot = tracks_[robot_id];
  if (!slot) {
    std::vector<std::string> names;
    for (const JointInfo& j : served.model.ActuatedJoints()) names.push_back(j.name);
    auto track = std::make_unique<Track>(std::move(names));
    track->robot_id = robot_id;
    // The registry outlives the service: an aliasing pointer that owns nothing.
    track->robot = std::shared_ptr<const RobotModel>(std::shared_ptr<const RobotModel>(), &served.model);
    auto tracker = Tracker::Create(track->robot);
    if (!tracker.ok()) {
      tracks_.erase(robot_id);
      return tracker.status().WithContext("tracking robot " + robot_id);
    }
    track->tracker.emplace(std::move(*tracker));
    Track* raw = track.get();
    if (!options_.process_inline) track->worker = std::thread([this, raw] { Work(*raw); });
    slot = std::move(track);
  }
  Track& t = *slot;
  std::lock_guard track_lock(t.mu);
  {
    std::lock_guard tracker_lock(t.tracker_mu);
    // Refused before anything changes: the robot's owner and stream stay as they were.
    ARREF_RETURN_IF_ERROR(t.tracker->SetCameraPoseLatency(camera_pose_latency_s));
    t.tracker->Seed(T_world_base_seed);
  }
  t.owner = session;
  t.owner_id = session->id();
  t.result_frame = result_frame;
  t.slot.reset();
  t.processed = t.dropped = 0;  // counts of this request's stream
  spdlog::info("tracking: robot {} for session {} (camera poses {} ms after exposure)", robot_id, session->id(),
               camera_pose_latency_s * 1e3);
  return Status::Ok();
}

void TrackingService::Stop(const std::string& robot_id, std::uint64_t session_id) {
  std::lock_guard lock(mu_);
  auto it = tracks_.find(robot_id);
  if (it == tracks_.end()) return;
  std::lock_guard track_lock(it->second->mu);
  if (it->second->owner_id == session_id) it->second->owner_id = 0, it->second->owner.reset(), it->second->slot.reset();
}

void TrackingService::RemoveSession(std::uint64_t session_id) {
  {
    std::lock_guard lock(mu_);
    clocks_.erase(session_id);
  }
  std::vector<std::string> ids;
  {
    std::lock_guard lock(mu_);
    for (auto& [id, t] : tracks_) ids.push_back(id);
  }
  for (const auto& id : ids) Stop(id, session_id);
}

Status TrackingService::AddJoints(const std::string& robot_id, std::uint64_t sender_session, double sender_time_s,
                                  const JointValues& joints) {
  const ClockEstimate clock = ClockOf(sender_session);
  std::lock_guard lock(mu_);
  auto it = tracks_.find(robot_id);
  if (it == tracks_.end()) return Status::Ok();  // nobody tracks it: nothing to keep
  Track& t = *it->second;
  std::lock_guard track_lock(t.mu);
  // A sender's new offset estimate can move its stamps back a little: such samples are
  // dropped (counted) rather than reorder the history.
  const double server_time = sender_time_s + clock.offset_s;
  if (!t.history.empty() && server_time <= t.history.newest_time_s()) {
    ++t.joints_out_of_order;
    return Status::Ok();
  }
  return t.history.Add(server_time, joints);
}

Status TrackingService::SubmitFrame(const std::string& robot_id, std::uint64_t session_id, std::uint64_t frame_id,
                                    DepthFrame frame) {
  const ClockEstimate clock = ClockOf(session_id);
  std::unique_lock lock(mu_);
  auto it = tracks_.find(robot_id);
  if (it == tracks_.end() || it->second->owner_id != session_id)
    return Status::FailedPrecondition(
        fmt::format("DepthFrame for robot '{}': this session asked for no tracking of it (TrackRequest)", robot_id));
  Track& t = *it->second;  // tracks are never erased once started
  frame.time_s += clock.offset_s;
  Pending job{std::move(frame), frame_id, SteadyClock::now(), clock};
  if (options_.process_inline) {
    lock.unlock();
    Process(t, std::move(job));
    return Status::Ok();
  }
  {
    std::lock_guard track_lock(t.mu);
    if (t.slot) ++t.dropped;  // newest wins
    t.slot = std::move(job);
  }
  t.wake.notify_one();
  return Status::Ok();
}

void TrackingService::Work(Track& t) {
  for (;;) {
    Pending job;
    {
      std::unique_lock lock(t.mu);
      t.wake.wait(lock, [&] { return t.stopping || t.slot.has_value(); });
      if (t.stopping) return;
      job = std::move(*t.slot);
      t.slot.reset();
    }
    Process(t, std::move(job));
  }
}

void TrackingService::Process(Track& t, Pending job) {
  std::shared_ptr<TrackingSink> owner;
  std::uint64_t owner_id = 0;
  FrameConvention result_frame = FrameConvention::kRos;
  Result<JointLookup> joints = Status::FailedPrecondition("no joint state");
  {
    std::lock_guard lock(t.mu);
    owner = t.owner.lock();
    owner_id = t.owner_id;
    result_frame = t.result_frame;
    joints = t.history.At(job.frame.time_s);
  }
  // Without a joint stream the robot is taken as standing at its zero pose.
  const JointValues values = joints.ok() ? joints->joints : JointValues{};
  Result<TrackResult> r = Status::Internal("not run");
  {
    std::lock_guard tracker_lock(t.tracker_mu);
    r = t.tracker->Process(job.frame, values);
  }
  pb::ServerMessage message;
  if (!r.ok()) {
    message = wire::ErrorMessage(pb::ERROR_CODE_BAD_DEPTH_FRAME,
                                 fmt::format("DepthFrame {}: {}", job.frame_id, r.status().message()));
  } else {
    std::uint64_t processed, dropped;
    {
      std::lock_guard lock(t.mu);
      processed = ++t.processed;
      dropped = t.dropped;
    }
    pb::TrackingUpdate* u = message.mutable_tracking_update();
    u->set_robot_id(t.robot_id);
    u->set_session_id(owner_id);
    u->set_frame_id(job.frame_id);
    u->set_frame_time_s(job.frame.time_s);
    u->set_frame_time_unix_s(options_.unix_time_of(job.frame.time_s));
    u->set_state(TrackStateName(r->state));
    *u->mutable_t_world_base() = wire::PoseToProto(r->T_world_base, result_frame);
    u->set_frame(wire::ToProto(result_frame));
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) u->add_covariance(r->covariance(i, j));
    u->mutable_joints()->set_robot_id(t.robot_id);
    u->mutable_joints()->set_timestamp_s(job.frame.time_s);
    for (const auto& [name, value] : values) {
      u->mutable_joints()->add_names(name);
      u->mutable_joints()->add_positions(value);
    }
    u->set_joint_staleness_s(joints.ok() ? joints->staleness_s : -1.0);
    u->set_clock_offset_s(job.clock.offset_s);
    u->set_clock_uncertainty_s(job.clock.uncertainty_s);
    u->set_process_ms(r->total_ms);
    u->set_frames_processed(processed);
    u->set_frames_dropped(dropped);
    u->set_agreement(r->agreement);
    u->set_depth_noise(r->depth_noise_fraction);
    u->set_latency_ms(MsSince(job.received));
  }
  const auto frame = wire::SharedFrame(message);
  if (owner) owner->SendFrame(frame);
  if (message.has_tracking_update()) hub_.Publish(t.robot_id, frame, owner_id);
}

}  // namespace arref::server
