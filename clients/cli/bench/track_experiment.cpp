// `arref bench --only track`: the tracker on simulated streams of every robot and
// frame kind, against ground truth, with a per-frame baseline measured in the same run (the
// one-shot way: the posed model sampled afresh and PCL ICP, on a subset of frames), the
// recovery after the world jump, and one long stream for drift and memory.
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <unistd.h>

#include "arref/base/builtin.h"
#include "arref/base/clock.h"
#include "arref/base/split_mix.h"
#include "arref/base/stats.h"
#include "arref/scene/metrics.h"
#include "arref/scene/sampling.h"
#include "arref/sim/track_simulator.h"
#include "arref/sim/track_stream.h"
#include "arref/track/tracker.h"
#include "bench.h"
#ifdef ARREF_WITH_PCL
#include "arref/baselines/baselines.h"
#endif

namespace arref::bench {
namespace {

double RssMb() {
  std::ifstream statm("/proc/self/statm");
  double pages = 0, resident = 0;
  statm >> pages >> resident;
  return resident * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

struct StreamStats {
  int frames = 0, scored = 0, within = 0, scored_steady = 0, within_steady = 0, lost = 0, no_robot = 0;
  // Re-references after the first frame: the filter's jumps and re-acquisitions, and those of
  // them before the simulated jump (the world had not moved: a wrong one).
  int jumps = 0, reacquired = 0, false_rereferences = 0;
  double model_points = 0;  // mean per frame
  double depth_noise = 0;   // the tracker's measure of the depth's noise at the last frame (sigma / range)
  double recovery_s = -1;  // < 0: no jump, or never recovered
  // From the first frame after the jump that shows the arm to the recovery (sim::JumpRecovery):
  // the part of it a tracker can answer for. < 0: not recovered.
  double recovery_after_shown_s = -1;
  bool had_jump = false;
  std::vector<double> add_mm, frame_ms, baseline_ms, baseline_add_mm;
  int baseline_failures = 0;  // baseline frames whose posing or ICP failed (not in its columns)
  std::vector<double> add_first_min_mm, add_last_min_mm;
  double rss_start_mb = 0, rss_end_mb = 0, duration_s = 0;
};

#ifdef ARREF_WITH_PCL
// One frame the one-shot way: the model posed (at the joints the tracker used, clamped into
// their limits as it clamps them) and sampled afresh, PCL ICP (the paper's best parameters) of it
// against the frame's depth points round the last estimate. Its time (ms) and ADD (mm).
Result<std::pair<double, double>> BaselineFrame(const RobotModel& robot, const sim::SimFrame& f, const JointValues& joints,
                                                const Iso3& T_world_base_initial, const std::vector<Vec3f>& add_points) {
  LapTimer lap;
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh mesh, robot.PosedMesh(robot.ClampedToLimits(joints)));
  const PointCloud model = SampleSurface(mesh, 10000, 1);
  const Aabb box = BoundsOf(model.points).Grown(0.3f);
  const Iso3 T_base_camera = T_world_base_initial.inverse() * f.frame.T_world_camera;
  PointCloud scene;
  const DepthIntrinsics& c = f.frame.intrinsics;
  for (int v = 0; v < c.height; v += 2)
    for (int u = 0; u < c.width; u += 2) {
      const float d = f.frame.DepthAt(u, v);
      if (d <= 0) continue;
      const Vec3 p = c.Ray(u, v) * d;
      if (!box.Contains((T_base_camera * p).cast<float>())) continue;
      scene.points.push_back((f.frame.T_world_camera * p).cast<float>());
    }
  ARREF_ASSIGN_OR_RETURN(const RegistrationOutput fit, RegisterPclIcp(model, scene, T_world_base_initial, IcpParams{}, false));
  const double ms = lap.Lap();
  return std::make_pair(ms, 1000 * ComparePoses(fit.T_world_base, f.T_world_base_true, add_points).add_m);
}
#endif

struct StreamSpec {
  std::shared_ptr<const RobotModel> robot;
  sim::TrackSimOptions options;
  double declared_latency_s = 0.0;  // the camera pose latency told to the tracker
  std::uint64_t seed = 1;
  int baseline_frames = 0;  // spread over the stream
  bool minutes = false;     // keep the first and last minute's ADD
};

// A pose's error in the true base's frame (x, y, z and yaw of T_base_true^-1 T): a bias shows
// as a sign that holds over frames, which ADD alone hides (how draw 18's echoing fits were found).
std::string ErrorInBase(const sim::SimFrame& f, const Iso3& T_world_base) {
  const Iso3 d = f.T_world_base_true.inverse() * T_world_base;
  const Vec3 t = 1000 * d.translation();
  return fmt::format("({:+.1f} {:+.1f} {:+.1f} mm {:+.2f} deg)", t.x(), t.y(), t.z(), YawOf(d) / kDegree);
}

Result<StreamStats> RunStream(const StreamSpec& spec) {
  ARREF_ASSIGN_OR_RETURN(sim::TrackSimulator simulator, sim::TrackSimulator::Create(spec.robot, spec.options, spec.seed));
  StreamStats s;
  s.duration_s = simulator.frame_count() / simulator.options().fps;
  const double jump = simulator.jump_time_s();
  s.had_jump = jump < s.duration_s;
  const int baseline_every = spec.baseline_frames > 0 ? std::max(1, simulator.frame_count() / spec.baseline_frames) : 0;
  sim::JumpRecovery recovery(jump);
  Iso3 last_estimate = simulator.T_world_base_initial();
  const int frame_count = simulator.frame_count();
  s.rss_start_mb = RssMb();
  auto on_step = [&](const sim::TrackStreamStep& step) {
    const sim::SimFrame& f = step.frame;
    const TrackResult& r = step.result;
    ++s.frames;
    s.frame_ms.push_back(r.total_ms);
    if (r.state == TrackState::kLost) ++s.lost;
    if (r.state == TrackState::kNoRobot) ++s.no_robot;
    if (step.index > 0 && (r.state == TrackState::kJump || r.state == TrackState::kReacquired)) {
      ++(r.state == TrackState::kJump ? s.jumps : s.reacquired);
      if (!f.after_jump) ++s.false_rereferences;
    }
    s.model_points += static_cast<double>(r.model_points) / frame_count;
    s.depth_noise = r.depth_noise_fraction;
    const double add_mm = 1000 * step.add_m;
    if (spdlog::should_log(spdlog::level::debug))
      spdlog::debug("track frame {} t {:.3f}: {} ADD {:.1f} mm {}, measured {:.1f} mm {}, agreement {:.2f} (filter {:.2f}), {} model / {} depth points, {:.1f} ms",
                    step.index, f.true_time_s, TrackStateName(r.state), add_mm, ErrorInBase(f, r.T_world_base),
                    r.T_world_base_measured ? 1000 * ComparePoses(*r.T_world_base_measured, f.T_world_base_true, step.add_points).add_m : -1.0,
                    r.T_world_base_measured ? ErrorInBase(f, *r.T_world_base_measured) : std::string(),
                    r.agreement, r.agreement_filtered, r.model_points, r.depth_points, r.total_ms);
    recovery.Add(step);
#ifdef ARREF_WITH_PCL
    if (baseline_every > 0 && step.index % baseline_every == baseline_every / 2 &&
        spec.options.kind == sim::FrameKind::kLongThrow) {
      auto baseline = BaselineFrame(*spec.robot, f, step.joints.joints, last_estimate, step.add_points);
      if (baseline.ok()) {
        s.baseline_ms.push_back(baseline->first);
        s.baseline_add_mm.push_back(baseline->second);
      } else {
        ++s.baseline_failures;
        spdlog::warn("bench: track baseline on frame {} of {} (simulator seed {}): {}", step.index, spec.robot->name(),
                     spec.seed, baseline.status().ToString());
      }
    }
#endif
    last_estimate = r.T_world_base;
    if (f.true_time_s < 1.0) return Status::Ok();
    s.add_mm.push_back(add_mm);
    ++s.scored;
    if (add_mm < 10) ++s.within;
    if (!sim::SettlingFrame(f, jump)) {
      ++s.scored_steady;
      if (add_mm < 10) ++s.within_steady;
    }
    if (spec.minutes && f.true_time_s < 61.0) s.add_first_min_mm.push_back(add_mm);
    if (spec.minutes && f.true_time_s >= s.duration_s - 60.0) s.add_last_min_mm.push_back(add_mm);
    return Status::Ok();
  };
  sim::TrackStreamOptions stream;
  stream.declared_pose_latency_s = spec.declared_latency_s;
  ARREF_RETURN_IF_ERROR(sim::RunTrackStream(spec.robot, simulator, stream, on_step));
  s.recovery_s = recovery.recovery_s();
  s.recovery_after_shown_s = recovery.after_shown_s();
  s.rss_end_mb = RssMb();
  return s;
}


// A stream of `robot` with the device's effects the bench was asked for, and the latency the
// device declares.
StreamSpec DeviceStream(const TrackConfig& tc, const BenchRobot& robot) {
  StreamSpec spec;
  spec.robot = robot.model;
  spec.options.flying_pixel_rate = tc.flying_pixel_rate;
  spec.options.depth_noise_fraction = tc.depth_noise_fraction;
  spec.options.pose_latency_s = tc.pose_latency_ms / 1000.0;
  spec.declared_latency_s = tc.declared_latency_ms / 1000.0;
  return spec;
}

std::string Pct(int a, int b) { return b ? fmt::format("{:.1f}", 100.0 * a / b) : "-"; }
std::string Num(double x, const char* f = "{:.1f}") { return std::isnan(x) ? "-" : fmt::format(fmt::runtime(f), x); }

}  // namespace

Status TrackExperiment(const Config& config, Tables* tables) {
  const TrackConfig& tc = config.track;
  const bool heldout = config.robustness.split == "heldout";
  ARREF_ASSIGN_OR_RETURN(const std::vector<BenchRobot> robots, LoadBenchRobots(config.robustness, heldout, "track"));
  // The held-out split draws from a stream of its own: none of its streams was seen while developing.
  const std::uint64_t stream = heldout ? SplitMix64(config.rng_seed ^ 0x48454C44u) : SplitMix64(config.rng_seed ^ 0x444556u);
  const std::string path = config.out_dir + "/track.md";
  std::ofstream md(path);
  if (!md) return Status::IoError("cannot write " + path);
  md << "# arref bench --only track (" << config.robustness.split << " split)\n\n";
  md << fmt::format("{} stream(s) of {:.0f} s per robot and frame kind; one world jump each (0.1-1 m, 5-30 deg) half way; "
                    "ADD against the simulator's truth; 'within 10 mm' counts frames after the first second, "
                    "'steady' also leaves out the second after the jump; recovery is the time from the jump to the first of 10 frames in a row within 10 mm, and 'after shown' the time from the first frame after the jump in which half of the arm's pixels in view are not hidden by props (a frame showing less cannot place it) to that recovery. Frame times are the tracker's own "
                    "(model, crop, ICP, filter); the baseline is the one-shot way per frame (posed model sampled "
                    "afresh, 10,000 points, PCL ICP 0.1 m / 500 iterations) on {} frames per long-throw stream.\n\n",
                    tc.streams, tc.seconds, tc.baseline_frames);
  if (tc.flying_pixel_rate > 0 || tc.pose_latency_ms != 0 || tc.declared_latency_ms != 0)
    md << fmt::format("Device effects on every stream: {:.0f} % of the pixels on depth edges fly (a depth between the "
                      "edge's two sides), and the camera pose is head tracking's {:.0f} ms after the exposure; the "
                      "tracker is told {:.0f} ms.\n\n",
                      100 * tc.flying_pixel_rate, tc.pose_latency_ms, tc.declared_latency_ms);
  if (tc.depth_noise_fraction > 0)
    md << fmt::format("Depth noise on every stream: sigma {:.1f} % of range (the frame kinds' own: 1 % long-throw, 0.3 % AHAT).\n\n",
                      100 * tc.depth_noise_fraction);
  md << "| robot | frames | streams | within 10 mm % | steady % | ADD median mm | ADD p95 mm | lost frames | "
        "recovery s (worst) | after shown s (worst) | frame ms median | frame ms p95 | baseline ms median | baseline / tracker | "
        "baseline ADD median mm |\n";
  md << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const std::string& kind_name : tc.kinds) {
    ARREF_ASSIGN_OR_RETURN(const sim::FrameKind kind, sim::ParseFrameKind(kind_name));
    for (const BenchRobot& robot : robots) {
      if (tc.streams == 0) break;
      StreamStats all;
      double worst_recovery = -1, worst_after_shown = -1;
      bool unrecovered = false;
      for (int k = 0; k < tc.streams; ++k) {
        StreamSpec spec = DeviceStream(tc, robot);
        spec.options.kind = kind;
        spec.options.duration_s = tc.seconds;
        spec.seed = SplitMix64(stream ^ SplitMix64(std::hash<std::string>{}(robot.label)) ^
                               SplitMix64(static_cast<std::uint64_t>(k) + 1) ^ SplitMix64(static_cast<std::uint64_t>(kind) + 77));
        spec.baseline_frames = tc.baseline_frames;
        ARREF_ASSIGN_OR_RETURN(const StreamStats s, RunStream(spec));
        all.frames += s.frames, all.scored += s.scored, all.within += s.within, all.lost += s.lost;
        all.scored_steady += s.scored_steady, all.within_steady += s.within_steady;
        all.baseline_failures += s.baseline_failures;
        for (auto [dst, src] : {std::pair{&all.add_mm, &s.add_mm}, {&all.frame_ms, &s.frame_ms},
                                {&all.baseline_ms, &s.baseline_ms}, {&all.baseline_add_mm, &s.baseline_add_mm}})
          dst->insert(dst->end(), src->begin(), src->end());
        if (s.had_jump && s.recovery_s < 0) unrecovered = true;
        worst_recovery = std::max(worst_recovery, s.recovery_s);
        worst_after_shown = std::max(worst_after_shown, s.recovery_after_shown_s);
        // The simulator's seed, so that a failing stream can be run again alone (sim::TrackSimulator).
        spdlog::info("bench: track {} {} stream {} (simulator seed {}): {}/{} within 10 mm, recovery {:.2f} s ({:.2f} s after the arm showed), frame "
                     "median {:.1f} ms, {} lost, {} without the robot in view, {:.0f} model points per frame, depth noise "
                     "measured {:.2f} % of range",
                     robot.label, kind_name, k, spec.seed, s.within, s.scored, s.recovery_s, s.recovery_after_shown_s,
                     Quantile(s.frame_ms, 0.5),
                     s.lost, s.no_robot, s.model_points, 100 * s.depth_noise);
      }
      const double median_ms = Quantile(all.frame_ms, 0.5), baseline_ms = Quantile(all.baseline_ms, 0.5);
      md << fmt::format("| {} ({}) | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n", robot.label,
                        kind_name, all.frames, tc.streams, Pct(all.within, all.scored), Pct(all.within_steady, all.scored_steady),
                        Num(Quantile(all.add_mm, 0.5)), Num(Quantile(all.add_mm, 0.95)), all.lost,
                        unrecovered ? "not recovered" : Num(worst_recovery, "{:.2f}"),
                        unrecovered ? "not recovered" : Num(worst_after_shown, "{:.2f}"), Num(median_ms),
                        Num(Quantile(all.frame_ms, 0.95)), Num(baseline_ms, "{:.0f}"),
                        all.baseline_ms.empty() ? "-" : fmt::format("{:.0f}x", baseline_ms / median_ms),
                        Num(Quantile(all.baseline_add_mm, 0.5)) +
                            (all.baseline_failures ? fmt::format(" ({} failed)", all.baseline_failures) : ""));
      md.flush();
    }
  }
  if (tc.long_minutes > 0) {
    // Drift and memory: long streams of every robot at the long-throw camera's own rate.
    md << fmt::format("\n## Long streams: long-throw, {:.0f} min at {:.0f} fps, {} per robot\n\n", tc.long_minutes, tc.long_fps,
                      tc.long_streams);
    md << "re-references: the filter's jumps / re-acquisitions after the first frame, and how many of them came before the "
          "simulated jump (wrong ones).\n\n";
    md << "| robot | stream | frames | within 10 mm % | steady % | ADD median first minute mm | ADD median last minute mm | "
          "ADD p95 last minute mm | ADD max last minute mm | recovery s | jumps / re-acquisitions (before the jump) | "
          "RSS start MB | RSS end MB | frame ms median |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const BenchRobot& robot : robots)
      for (int k = 0; k < tc.long_streams; ++k) {
        StreamSpec spec = DeviceStream(tc, robot);
        spec.options.duration_s = 60.0 * tc.long_minutes;
        spec.options.fps = tc.long_fps;
        spec.seed = SplitMix64(stream ^ 0x4C4F4E47ull ^ SplitMix64(std::hash<std::string>{}(robot.label) + static_cast<std::uint64_t>(k)));
        spec.minutes = true;
        ARREF_ASSIGN_OR_RETURN(const StreamStats s, RunStream(spec));
        const double max_last = s.add_last_min_mm.empty()
                                    ? std::nan("")
                                    : *std::max_element(s.add_last_min_mm.begin(), s.add_last_min_mm.end());
        spdlog::info("bench: track long {} stream {}: {}/{} within 10 mm, last minute median {:.1f} mm, {} jumps, {} re-acquisitions",
                     robot.label, k, s.within, s.scored, Quantile(s.add_last_min_mm, 0.5), s.jumps, s.reacquired);
        md << fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} / {} ({}) | {:.1f} | {:.1f} | {} |\n", robot.label, k,
                          s.frames, Pct(s.within, s.scored), Pct(s.within_steady, s.scored_steady),
                          Num(Quantile(s.add_first_min_mm, 0.5)), Num(Quantile(s.add_last_min_mm, 0.5)),
                          Num(Quantile(s.add_last_min_mm, 0.95)), Num(max_last), Num(s.recovery_s, "{:.2f}"), s.jumps,
                          s.reacquired, s.false_rereferences, s.rss_start_mb, s.rss_end_mb, Num(Quantile(s.frame_ms, 0.5)));
        md.flush();
      }
  }
  tables->notes.push_back("track: see track.md (" + config.robustness.split + " split)");
  spdlog::info("bench: track table in {}", path);
  return Status::Ok();
}

}  // namespace arref::bench
