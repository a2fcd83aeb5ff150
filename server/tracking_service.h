// Continuous referencing in the server: per tracked robot, a joint-state history
// on the server's clock, a Tracker and one worker thread. A frame waits in a single slot
// while the one before it is processed; a newer frame replaces it (dropped, counted), so no
// queue grows and the newest frame wins. Every processed frame becomes a TrackingUpdate for
// the session that sent it and for the robot's subscribers. Thread-safe.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "arref/base/frames.h"
#include "arref/base/status.h"
#include "arref/track/depth_frame.h"
#include "arref/track/joint_history.h"
#include "arref/track/tracker.h"

namespace arref::server {

class SubscriberHub;
struct ServedRobot;

// Where a tracked robot's updates for the session that asked for them go: a live Session, or
// the offline replay. SendFrame must be thread-safe (a worker thread calls it).
class TrackingSink {
 public:
  virtual ~TrackingSink() = default;
  virtual std::uint64_t id() const = 0;
  virtual void SendFrame(std::shared_ptr<const std::string> frame) = 0;
};

struct ClockEstimate {
  double offset_s = 0.0;  // server clock minus the sender's
  double uncertainty_s = 0.0;
  bool reported = false;
};

struct TrackingServiceOptions {
  // true: each frame is processed in SubmitFrame's caller, none dropped, no threads (the offline
  // replay, which must give the same updates however fast the machine is); false: one worker
  // thread per robot, the newest frame wins (the server).
  bool process_inline = false;
  // A time on the server's clock as Unix time (TrackingUpdate.frame_time_unix_s); empty: by
  // the wall clock now (UnixTimeOf). The replay maps it by the recording's clocks.
  std::function<double(double server_time_s)> unix_time_of;
};

class TrackingService {
 public:
  explicit TrackingService(SubscriberHub& hub, TrackingServiceOptions options = {});
  ~TrackingService();  // Shutdown()
  // Stops and joins every worker (before the sessions' I/O goes away).
  void Shutdown();

  // Starts tracking `robot` with `session`'s frames from a first guess (replacing an earlier
  // request of any session), or stops it. camera_pose_latency_s: how late the session's device
  // stamps its camera poses (TrackRequest.camera_pose_latency_s; Tracker::SetCameraPoseLatency).
  Status Start(const ServedRobot& robot, const std::string& robot_id, const std::shared_ptr<TrackingSink>& session,
               const Iso3& T_world_base_seed, FrameConvention result_frame, double camera_pose_latency_s = 0.0);
  void Stop(const std::string& robot_id, std::uint64_t session_id);
  // A joint sample stamped on the sender's clock (complete values of the robot's actuated joints).
  Status AddJoints(const std::string& robot_id, std::uint64_t sender_session, double sender_time_s,
                   const JointValues& joints);
  void ReportClock(std::uint64_t session_id, const ClockEstimate& clock);
  // A frame stamped on the sender's clock. NOT_TRACKING-like FailedPrecondition when this
  // session asked for no tracking of the robot.
  Status SubmitFrame(const std::string& robot_id, std::uint64_t session_id, std::uint64_t frame_id, DepthFrame frame);
  void RemoveSession(std::uint64_t session_id);
  static double Now();  // the server's clock (steady, seconds), as Pong reports it
  // A time on that clock as Unix time, by the wall clock now (what ROS stamps with).
  static double UnixTimeOf(double server_time_s);

 private:
  struct Track;
  ClockEstimate ClockOf(std::uint64_t session_id);
  void Work(Track& track);
  struct Pending;
  void Process(Track& track, Pending job);  // one frame: tracker, then the update to the sinks
  SubscriberHub& hub_;
  TrackingServiceOptions options_;
  std::mutex mu_;
  std::map<std::string, std::unique_ptr<Track>> tracks_;
  std::map<std::uint64_t, ClockEstimate> clocks_;
};

}  // namespace arref::server
