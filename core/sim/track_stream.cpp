#include "arref/sim/track_stream.h"

#include <algorithm>
#include <string>
#include <vector>

#include "arref/scene/metrics.h"
#include "arref/scene/sampling.h"
#include "arref/track/clock_sync.h"

namespace arref::sim {

Status RunTrackStream(const std::shared_ptr<const RobotModel>& robot, TrackSimulator& simulator,
                      const TrackStreamOptions& options, const std::function<Status(const TrackStreamStep&)>& on_step) {
  if (!robot) return Status::InvalidArgument("track stream: no robot");
  if (options.round_trip_every < 1) return Status::InvalidArgument("track stream: round_trip_every must be >= 1");
  ARREF_ASSIGN_OR_RETURN(Tracker tracker, Tracker::Create(robot, options.tracker));
  std::vector<std::string> names;
  for (const JointInfo& j : robot->ActuatedJoints()) names.push_back(j.name);
  JointHistory history(names);
  ClockOffsetEstimator clock;
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh home, robot->PosedMesh({}));
  const std::vector<Vec3f> add_points = SampleSurface(home, 2000, 1).points;
  tracker.Seed(options.first_guess ? *options.first_guess : simulator.T_world_base_guess());
  ARREF_RETURN_IF_ERROR(tracker.SetCameraPoseLatency(options.declared_pose_latency_s).WithContext("track stream"));
  double last = -1.0;
  for (int i = 0; i < simulator.frame_count(); ++i) {
    ARREF_ASSIGN_OR_RETURN(const SimFrame f, simulator.Next());
    // Joint states and round trips as the server sees them: kept on the sender's clock, looked
    // up at the frame's time moved onto it by the estimated offset.
    if (i % options.round_trip_every == 0) ARREF_RETURN_IF_ERROR(clock.Add(simulator.RoundTrip(f.true_time_s)));
    for (const SimJointSample& js : simulator.JointSamples(last, f.true_time_s))
      ARREF_RETURN_IF_ERROR(history.Add(js.sender_time_s, js.joints));
    last = f.true_time_s;
    ARREF_ASSIGN_OR_RETURN(const JointLookup joints, history.At(f.frame.time_s - clock.offset_s()));
    ARREF_ASSIGN_OR_RETURN(const TrackResult r, tracker.Process(f.frame, joints.joints));
    const double add_m = ComparePoses(r.T_world_base, f.T_world_base_true, add_points).add_m;
    ARREF_RETURN_IF_ERROR(on_step(TrackStreamStep{i, f, joints, r, add_m, add_points}));
  }
  return Status::Ok();
}

bool SettlingFrame(const SimFrame& f, double jump_time_s) {
  return f.true_time_s < 1.0 || (f.after_jump && f.true_time_s < jump_time_s + 1.0);
}

void JumpRecovery::Add(const TrackStreamStep& step) {
  const SimFrame& f = step.frame;
  if (!f.after_jump || recovered()) return;
  if (shown_at_s_ < 0 && f.robot_visible_fraction >= kArmShows) shown_at_s_ = f.true_time_s;
  if (step.add_m >= kWithinM) {
    run_start_s_ = -1, run_ = 0;
    return;
  }
  if (run_++ == 0) run_start_s_ = f.true_time_s;
  if (run_ < kSettledFrames) return;
  recovery_s_ = run_start_s_ - jump_time_s_;
  // Recovered before the arm showed: the pose was held or found on what was seen.
  after_shown_s_ = shown_at_s_ < 0 ? 0.0 : std::max(0.0, run_start_s_ - shown_at_s_);
}

}  // namespace arref::sim
