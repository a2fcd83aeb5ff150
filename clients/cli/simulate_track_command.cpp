// `arref simulate-track`: a simulated tracking stream (sim/track_simulator.h) as the messages a
// client sends, with ground truth, so that clients in other languages can drive the server's
// continuous referencing with the same data as the C++ mock headset.
//
// The stream is a recording (proto/arref/v1/arref.proto, "recordings"): a TrackRequest whose
// seed is a few centimetres and degrees off the truth, then the joint states and depth frames in
// the order of their times, each RecordedMessage.t_s its true time. Every timestamp_s is on the
// stream's own clock (0 at the start, the joint sender and the headset on the same clock); a
// sender adds its own clock's time of the start. The truth JSON holds T_world_base of every frame.
#include <spdlog/spdlog.h>

#include <nlohmann/json.hpp>

#include <algorithm>

#include "arref/sim/track_simulator.h"
#include "cli_common.h"
#include "commands.h"
#include "convert.h"
#include "recording.h"

namespace arref::cli {
namespace {

namespace pb = wire::pb;

struct SimulateTrackArgs {
  RobotArgs robot;
  std::string robot_id = "kr5";
  std::string stream_out = "track.arrec";
  std::string truth_out = "track_truth.json";
  std::string kind = "long-throw";
  double seconds = 3.0;
  double jump_at = -1.0;
  std::uint64_t rng_seed = 1;
  double pose_latency_ms = 0.0;  // each frame's camera pose is head tracking's this long after the exposure
  bool declare_latency = false;  // and the TrackRequest says so, as a device that knows it
  double depth_noise = 0.0;      // sigma / range; 0: the frame kind's own
};

pb::ClientMessage TrackRequestMessage(const SimulateTrackArgs& args, const Iso3& seed) {
  pb::ClientMessage m;
  pb::TrackRequest* r = m.mutable_track_request();
  r->set_robot_id(args.robot_id);
  r->set_result_frame(pb::FRAME_CONVENTION_ROS);
  *r->mutable_seed()->mutable_t_world_seed() = wire::PoseToProto(seed, FrameConvention::kRos);
  r->mutable_seed()->set_frame(pb::FRAME_CONVENTION_ROS);
  if (args.declare_latency) r->set_camera_pose_latency_s(args.pose_latency_ms / 1000.0);
  return m;
}

pb::ClientMessage JointMessage(const std::string& robot_id, const sim::SimJointSample& sample) {
  pb::ClientMessage m;
  pb::JointState* j = m.mutable_joint_state();
  j->set_robot_id(robot_id);
  j->set_timestamp_s(sample.sender_time_s);
  for (const auto& [name, value] : sample.joints) j->add_names(name), j->add_positions(value);
  return m;
}

int Run(const SimulateTrackArgs& args) {
  auto loaded = LoadRobot(args.robot);
  if (!loaded.ok()) return Fail(loaded.status());
  auto robot = std::make_shared<const RobotModel>(std::move(*loaded));
  auto kind = sim::ParseFrameKind(args.kind);
  if (!kind.ok()) return Fail(kind.status());
  sim::TrackSimOptions options;
  options.kind = *kind;
  options.duration_s = args.seconds;
  options.jump_at_s = args.jump_at;
  options.sender_clock_offset_s = 0.0;  // one clock for the whole stream: the sender's own
  options.pose_latency_s = args.pose_latency_ms / 1000.0;
  options.depth_noise_fraction = args.depth_noise;
  auto simulator = sim::TrackSimulator::Create(robot, options, args.rng_seed);
  if (!simulator.ok()) return Fail(simulator.status().WithContext("simulating the track"));

  pb::RecordingHeader header;
  header.set_client_name("arref simulate-track");
  header.set_protocol_version(wire::kProtocolVersion);
  auto writer = wire::RecordingWriter::Create(args.stream_out, header);
  if (!writer.ok()) return Fail(writer.status());
  // A seed as a one-shot registration leaves it (the mock headset's).
  const Iso3 seed = simulator->T_world_base_initial() * MakeYawPose(0.03, -0.02, 0.01, 0.05);
  if (auto st = (*writer)->Append(0.0, TrackRequestMessage(args, seed)); !st.ok()) return Fail(st);

  nlohmann::json truth;
  truth["robot"] = robot->name();
  truth["robot_id"] = args.robot_id;
  truth["kind"] = args.kind;
  truth["rng_seed"] = args.rng_seed;
  truth["seconds"] = args.seconds;
  truth["jump_time_s"] = simulator->jump_time_s();
  truth["seed"] = PoseToJson(seed, FrameConvention::kRos);
  truth["frames"] = nlohmann::json::array();
  double last_time = -1.0;
  for (int i = 0; i < simulator->frame_count(); ++i) {
    auto f = simulator->Next();
    if (!f.ok()) return Fail(f.status());
    for (const auto& sample : simulator->JointSamples(last_time, f->true_time_s))
      if (auto st = (*writer)->Append(std::max(0.0, sample.sender_time_s), JointMessage(args.robot_id, sample)); !st.ok())
        return Fail(st);
    last_time = f->true_time_s;
    const std::uint64_t frame_id = static_cast<std::uint64_t>(i) + 1;
    f->frame.time_s = f->true_time_s;
    pb::ClientMessage m;
    *m.mutable_depth_frame() = wire::DepthFrameToProto(f->frame, FrameConvention::kRos);
    m.mutable_depth_frame()->set_robot_id(args.robot_id);
    m.mutable_depth_frame()->set_frame_id(frame_id);
    if (auto st = (*writer)->Append(f->true_time_s, m); !st.ok()) return Fail(st);
    truth["frames"].push_back({{"frame_id", frame_id},
                               {"t_s", f->true_time_s},
                               {"after_jump", f->after_jump},
                               {"T_world_base", MatrixToJson(f->T_world_base_true)},
                               {"joints", f->joints_true}});
  }
  if (auto st = WriteJsonFile(truth, args.truth_out); !st.ok()) return Fail(st);
  spdlog::info("wrote {} ({} {} frames over {:.1f} s, robot '{}') and {}", args.stream_out, simulator->frame_count(),
               args.kind, args.seconds, args.robot_id, args.truth_out);
  return kExitOk;
}

}  // namespace

void AddSimulateTrackCommand(CLI::App& app, int* exit_code) {
  auto args = std::make_shared<SimulateTrackArgs>();
  CLI::App* cmd = app.add_subcommand(
      "simulate-track", "Simulate a tracking stream (depth frames, joint states) as a recording, with ground truth");
  AddRobotOptions(*cmd, args->robot);
  cmd->add_option("--robot-id", args->robot_id, "Robot id the messages name (as the server serves the robot)")
      ->capture_default_str();
  cmd->add_option("--stream-out", args->stream_out, "Recording of the stream to write")->capture_default_str();
  cmd->add_option("--truth-out", args->truth_out, "Ground truth JSON to write (T_world_base per frame)")
      ->capture_default_str();
  cmd->add_option("--kind", args->kind, "Depth camera: long-throw or ahat")
      ->check(CLI::IsMember({"long-throw", "ahat"}))->capture_default_str();
  cmd->add_option("--seconds", args->seconds, "Stream length")->check(CLI::Range(0.1, 600.0))->capture_default_str();
  cmd->add_option("--jump-at", args->jump_at, "Time of the headset's world jump, s (< 0: half way; past the end: none)")
      ->capture_default_str();
  cmd->add_option("--rng-seed", args->rng_seed, "Random seed (same seed, same stream)")->capture_default_str();
  cmd->add_option("--pose-latency-ms", args->pose_latency_ms,
                  "Each frame's camera pose is head tracking's this long after the exposure (ms)")
      ->check(CLI::Range(0.0, 1000.0))->capture_default_str();
  cmd->add_flag("--declare-latency", args->declare_latency, "Say that latency in the stream's TrackRequest");
  cmd->add_option("--depth-noise", args->depth_noise,
                  "Depth noise sigma as a fraction of range (0: the frame kind's own, 0.01 long-throw, 0.003 AHAT)")
      ->check(CLI::Range(0.0, 0.2))->capture_default_str();
  cmd->callback([args, exit_code] { *exit_code = Run(*args); });
}

}  // namespace arref::cli
