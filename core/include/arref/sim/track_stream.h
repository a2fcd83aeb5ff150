// A simulated tracking stream fed to a tracker the way the server feeds a headset's: the
// sender's round trips into the clock estimator, its joint samples into the joint history,
// and each depth frame registered at the joints looked up at the frame's time moved onto the
// sender's clock. `arref bench --only track` and the tracker's tests both run streams through
// this one driver, so a bench stream's result reproduces in a test by its simulator seed.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/robot/robot_model.h"
#include "arref/sim/track_simulator.h"
#include "arref/track/joint_history.h"
#include "arref/track/tracker.h"

namespace arref::sim {

struct TrackStreamOptions {
  int round_trip_every = 10;        // frames between the sender's clock exchanges
  std::optional<Iso3> first_guess;  // the tracker's seed; none: the simulator's T_world_base_guess
  // The camera pose latency the sender declares (Tracker::SetCameraPoseLatency): the simulator's
  // own TrackSimOptions::pose_latency_s when the device's is known, 0 when it is not said.
  double declared_pose_latency_s = 0.0;
  TrackerSettings tracker;
};

// One processed frame, as the driver hands it to its caller.
struct TrackStreamStep {
  int index = 0;
  const SimFrame& frame;
  const JointLookup& joints;
  const TrackResult& result;
  double add_m = 0.0;  // ADD of result.T_world_base against the truth
  const std::vector<Vec3f>& add_points;  // the robot's samples that ADD is taken over (2,000, at home)
};

// Runs a fresh simulator's frames, from its first, through a new tracker, calling on_step after
// each; an error from the simulator, the clock, the history, the tracker or on_step ends the
// stream and is returned.
Status RunTrackStream(const std::shared_ptr<const RobotModel>& robot, TrackSimulator& simulator,
                      const TrackStreamOptions& options, const std::function<Status(const TrackStreamStep&)>& on_step);

// A frame in the stream's first second or in the second after the jump: the bench's "steady"
// share and the tracker's tests leave these out (the tracker may still be settling).
bool SettlingFrame(const SimFrame& f, double jump_time_s);

// Recovery after the world jump: from the jump to the first of kSettledFrames frames in a row
// within 10 mm; and from the first frame after the jump that shows half of the arm's pixels in
// view (a frame showing less cannot place it) to that recovery: the part a tracker answers for.
class JumpRecovery {
 public:
  static constexpr int kSettledFrames = 10;
  static constexpr double kArmShows = 0.5;
  static constexpr double kWithinM = 0.010;

  explicit JumpRecovery(double jump_time_s) : jump_time_s_(jump_time_s) {}
  void Add(const TrackStreamStep& step);
  bool recovered() const { return recovery_s_ >= 0; }
  double recovery_s() const { return recovery_s_; }             // < 0: not (yet) recovered
  double after_shown_s() const { return after_shown_s_; }       // < 0: not (yet) recovered

 private:
  double jump_time_s_;
  double run_start_s_ = -1, shown_at_s_ = -1;
  int run_ = 0;
  double recovery_s_ = -1, after_shown_s_ = -1;
};

}  // namespace arref::sim
