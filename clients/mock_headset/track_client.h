// A tracking headset and a robot-side joint sender against arref-server: the
// headset streams simulated depth frames (sim/track_simulator.h) in real time, the sender
// streams joint states on its own clock, both estimate their clock's offset from Ping/Pong
// round trips and report it; the TrackingUpdates are compared with the simulator's truth.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "arref/base/status.h"
#include "headset_client.h"

namespace arref::headset {

struct TrackHeadsetOptions {
  std::string host = "127.0.0.1";
  std::uint16_t port = 7311;
  std::string robot_id = "kr5";
  std::string kind = "long-throw";  // or "ahat"
  double duration_s = 4.0;
  double jump_at_s = -1.0;          // < 0: half way
  std::uint64_t rng_seed = 1;
  // Frames sent this many at once (the rest of the time the stream is real time): a burst
  // arrives faster than the server processes it, so all but the newest are dropped.
  int burst = 1;
  // A real device's effects (sim::TrackSimOptions): mixed pixels on depth edges, a late pose.
  double flying_pixel_rate = 0.0;
  double pose_latency_s = 0.0;
  double depth_noise_fraction = 0.0;  // sigma / range; 0: the frame kind's own (1 % long-throw, 0.3 % AHAT)
  bool declare_latency = false;     // say pose_latency_s in the TrackRequest, as a device that knows it
  double headset_clock_offset_s = 12.5;   // the headset's clock runs this far ahead of the machine's
  double sender_clock_offset_s = -0.73;   // the joint sender's
  bool subscriber = true;           // a third session subscribes to the robot's updates
  double timeout_s = 60.0;
  TlsClientOptions tls;
};

struct TrackUpdateRecord {
  std::uint64_t frame_id = 0;
  std::string state;
  double add_mm = 0.0;        // against the truth of that frame
  double latency_ms = 0.0;    // frame sent -> update received (client side)
  double server_latency_ms = 0.0, process_ms = 0.0;
  double true_time_s = 0.0;
  bool after_jump = false;
  // TrackingUpdate.frame_time_unix_s minus the exposure's Unix time on this machine's clock.
  double unix_time_error_s = 0.0;
  double depth_noise = 0.0;   // TrackingUpdate.depth_noise: the server's measure of the depth's noise
};

struct TrackHeadsetRun {
  Status status;
  int frames_sent = 0;
  std::vector<TrackUpdateRecord> updates;
  std::uint64_t frames_dropped = 0;   // as the server last reported
  int subscriber_updates = 0;
  double reported_offset_error_s = 0.0;  // the headset's clock report against the truth
  double jump_time_s = 0.0;
  double frames_per_s = 0.0;  // the stream's frame rate
  std::vector<pb::Error> errors;
};

TrackHeadsetRun RunTrackingHeadset(const TrackHeadsetOptions& options);

// Which of run.updates count as settled (the "after the first second", and a jump's
// "within 1 s of frames"): an update at least 1 s past the stream's start, and past the jump when
// it follows it, once the server has also processed more than a second's worth of frames since
// each. A server under load drops frames, and the filter settles over the frames it processed,
// not over wall time.
std::vector<bool> SettledUpdates(const TrackHeadsetRun& run);

}  // namespace arref::headset
