// A simulated tracking stream with ground truth: a robot moving along joint-space
// splines, a wearer walking round it, depth frames like HoloLens 2's long-throw or AHAT
// camera, a joint-state sender on its own clock, head-tracking drift and one re-localisation
// jump of the headset's world. Frames come one at a time (a 10-minute stream never sits in
// memory).
#pragma once

#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/robot/robot_model.h"
#include "arref/sim/cell_simulator.h"
#include "arref/track/clock_sync.h"
#include "arref/track/depth_frame.h"

namespace arref::sim {

enum class FrameKind { kLongThrow, kAhat };
const char* FrameKindName(FrameKind kind);  // "long-throw", "ahat"
Result<FrameKind> ParseFrameKind(const std::string& name);

struct TrackSimOptions {
  FrameKind kind = FrameKind::kLongThrow;
  double duration_s = 20.0;
  double fps = 0.0;               // 0: 30 for long-throw, 45 for AHAT
  // The robot: smooth steps between random joint targets (zero velocity at each), never faster
  // than max_joint_speed; targets within joint_range_rad of zero (and the limits).
  double max_joint_speed_rad_s = 1.0;
  double knot_interval_s = 1.5;
  double joint_range_rad = 0.9;
  double joint_rate_hz = 200.0;   // joint states sent
  double joint_stamp_jitter_s = 0.001;
  // The sender's clock runs this far from the headset's; its round trips to the server take
  // 1 ms plus an exponential delay of this mean each way.
  double sender_clock_offset_s = -0.73;
  double network_delay_mean_s = 0.004;
  // The wearer walks back and forth over an arc round the robot.
  double walk_radius_m = 0.0;     // 0: 1.9 m long-throw, 1.2 m AHAT
  double walk_arc_deg = 140.0;
  double walk_speed_m_s = 0.5;
  double eye_height_m = 1.65;
  double head_wander_deg = 4.0;
  // The depth camera.
  double depth_noise_fraction = 0.0;  // sigma as a fraction of depth; 0: 1 % long-throw, 0.3 % AHAT
  double depth_noise_floor_m = 0.0;   // added sigma; 0: none long-throw, 2 mm AHAT
  double dropout = 0.02;              // pixels with no return
  // Mixed ("flying") pixels of a time-of-flight camera: a pixel on a depth edge (a 4-neighbour
  // more than flying_edge_m nearer or farther) returns, with this probability, a depth drawn
  // uniformly between its own and that neighbour's. 0: none (the simulator's default).
  double flying_pixel_rate = 0.0;
  double flying_edge_m = 0.05;
  // Per-frame error of the camera pose the headset reports (not part of the truth: the
  // headset's world is where its tracking puts it on average), as the mapping simulator's.
  double pose_jitter_m = 0.004;
  double pose_jitter_deg = 0.3;
  // The reported camera pose is head tracking's at exposure plus this (s): a device whose pose
  // and depth stamps disagree. 0: none (the simulator's default).
  double pose_latency_s = 0.0;
  // Head-tracking drift of the headset's world (random walk per sqrt(s)) and one jump.
  double drift_m_per_sqrt_s = 0.0015;
  double drift_deg_per_sqrt_s = 0.03;
  double jump_at_s = -1.0;            // < 0: half way; > duration: none
  double jump_min_m = 0.1, jump_max_m = 1.0;
  double jump_min_deg = 5.0, jump_max_deg = 30.0;
  CellOptions cell;                   // props round the robot (the robot itself is posed per frame)
};

struct SimJointSample {
  double sender_time_s = 0.0;  // the sender's clock
  JointValues joints;
};

struct SimFrame {
  DepthFrame frame;
  Iso3 T_world_base_true = Iso3::Identity();  // in the headset's world at that instant
  JointValues joints_true;                    // at exposure
  bool after_jump = false;
  double true_time_s = 0.0;
  // Of the robot's pixels in the image, the share no prop hides (0 with none in view): a frame
  // that shows little of the arm cannot place it, whatever the tracker does.
  double robot_visible_fraction = 0.0;
};

class TrackSimulator {
 public:
  static Result<TrackSimulator> Create(std::shared_ptr<const RobotModel> robot, const TrackSimOptions& options,
                                       std::uint64_t rng_seed);
  TrackSimulator(TrackSimulator&&) noexcept;
  TrackSimulator& operator=(TrackSimulator&&) noexcept;
  ~TrackSimulator();

  const TrackSimOptions& options() const;
  int frame_count() const;
  double jump_time_s() const;  // headset clock; > duration: none
  // The next frame, in order (FailedPrecondition after the last).
  Result<SimFrame> Next();
  // Joint states the sender stamps in (t0, t1] of true time, in order.
  std::vector<SimJointSample> JointSamples(double t0_s, double t1_s) const;
  // One timestamped round trip between the sender and the server (whose clock is the
  // headset's here), with random network delays.
  ClockExchange RoundTrip(double true_time_s);
  // The truth at true time t, for tests.
  JointValues JointsAt(double t_s) const;
  // Where the first frame will see the robot, for the tracker's seed.
  Iso3 T_world_base_initial() const;
  // A first guess of it as a one-shot registration leaves it, or a user's good guess: up to 4 cm
  // across, 2 cm in height and 4 deg of yaw off, drawn from the simulator's seed (the bench's).
  Iso3 T_world_base_guess() const;

 private:
  struct Impl;
  explicit TrackSimulator(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace arref::sim
