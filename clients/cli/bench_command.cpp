// `arref bench`: reproduces the paper's experiments on simulated cells with ground truth.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <sstream>

#include "bench/bench.h"
#include "cli_common.h"
#include "commands.h"

namespace arref::cli {
namespace {

struct BenchArgs {
  RobotArgs robot;
  std::string methods = "pcl-icp,super4pcs";
  std::string perturb_methods = "pcl-icp";
  std::string scene_methods;  // default: methods
  std::string out;
  bool quick = false;
  bool no_big = false;
  int jobs = 1;
  std::uint64_t rng_seed = 1;
  std::vector<std::string> scene_kinds;
  std::string scene_size = "small";
  int scene_cells = 2;
  int scene_seeds = 3;
  bool seed_any_yaw = false;
  bool walk_any_side = false;
  bool varied_walk = false;
  bool head_path = false;
  double walk_arc_deg = 0.0;
  double seed_max_offset = 0.0;
  double pose_jitter = -1;
  double tracking_error = -1;
  std::string images;  // scenes experiment: pictures of results go here
  std::string only;  // comma-separated subset of sweep, perturb, scenes, robustness
  std::vector<std::string> robots;  // robustness: URDFs; default builtin plus ../shared/robots
  std::vector<std::string> meshers = {"own", "open3d"};
  std::vector<std::string> seed_families = {"user", "cube", "any-yaw"};
  std::string robust_methods = "arref-icp";
  std::string split = "dev";
  std::string heldout_robot = "sia10d";
  int robust_cells = 4;
  int robust_seeds = 2;
  std::vector<std::string> robust_without;
  std::string mapping_motion = "none", moving_fit = "auto";
  bool robust_pedestals = false;
  bool robust_own_voxels = false;
  std::string auto_methods = "arref-auto,sliding-box-shot,super4pcs,fpfh-ransac";
  int auto_rooms = 2;
  std::vector<int> auto_arms = {0, 1, 2};
  bool auto_truth_seeds = false;
  bench::TrackConfig track;
  std::string command_line;
};

Result<std::vector<std::string>> ParseMethodList(const std::string& text, const char* option) {
  std::vector<std::string> names;
  std::stringstream ss(text);
  for (std::string name; std::getline(ss, name, ',');) {
    if (name.empty()) continue;
    if (auto m = ParseMethod(name); !m.ok()) return m.status().WithContext(option);
    names.push_back(name);
  }
  return names;
}

int Run(const BenchArgs& args) {
  bench::Config config;
  auto methods = ParseMethodList(args.methods, "--methods");
  if (!methods.ok()) return Fail(methods.status());
  auto perturb = ParseMethodList(args.perturb_methods, "--perturb-methods");
  if (!perturb.ok()) return Fail(perturb.status());
  auto scenes = ParseMethodList(args.scene_methods.empty() ? args.methods : args.scene_methods, "--scene-methods");
  if (!scenes.ok()) return Fail(scenes.status());
  config.methods = *methods, config.perturb_methods = *perturb, config.scene_methods = *scenes;
  config.out_dir = args.out, config.quick = args.quick, config.big = !args.no_big;
  config.images_dir = args.images;
  config.jobs = args.jobs, config.rng_seed = args.rng_seed;
  config.scene_size = args.scene_size, config.scene_cells = args.scene_cells, config.scene_seeds = args.scene_seeds;
  if (!args.scene_kinds.empty()) config.scene_kinds = args.scene_kinds;
  config.variation.seed_noise.any_yaw = args.seed_any_yaw;
  config.variation.seed_noise.max_horizontal_m = args.seed_max_offset;
  config.variation.walk_any_side = args.walk_any_side;
  config.variation.varied_walk = args.varied_walk;
  config.head_path = args.head_path;
  config.variation.walk_arc_deg = args.walk_arc_deg;
  config.variation.pose_jitter_m = args.pose_jitter;
  config.tracking_error_m = args.tracking_error;
  auto robust_methods = ParseMethodList(args.robust_methods, "--robust-methods");
  if (!robust_methods.ok()) return Fail(robust_methods.status());
  bench::RobustnessConfig& rc = config.robustness;
  rc.methods = *robust_methods, rc.meshers = args.meshers, rc.seed_families = args.seed_families;
  rc.split = args.split, rc.heldout_robot = args.heldout_robot, rc.cells = args.robust_cells, rc.seeds = args.robust_seeds;
  rc.without = args.robust_without;
  rc.motion = args.mapping_motion;
  rc.moving_fit = args.moving_fit;
  rc.pedestals = args.robust_pedestals;
  rc.own_voxels = args.robust_own_voxels;
  rc.package_path = args.robot.package_path;
  auto auto_methods = ParseMethodList(args.auto_methods, "--auto-methods");
  if (!auto_methods.ok()) return Fail(auto_methods.status());
  config.auto_methods = *auto_methods, config.auto_rooms = args.auto_rooms;
  config.auto_arms = args.auto_arms, config.auto_truth_seeds = args.auto_truth_seeds;
  rc.robots = args.robots;
  config.track = args.track;
  if (rc.robots.empty()) {
    // The built-in robot, and every vendor package beside the checkout (when it is there).
    rc.robots.push_back("builtin");
    const std::filesystem::path shared = "../shared/robots";
    std::vector<std::string> found;
    std::error_code scan;
    if (std::filesystem::is_directory(shared, scan)) {
      for (const auto& package : std::filesystem::directory_iterator(shared, scan))
        if (std::filesystem::is_directory(package.path() / "urdf", scan))
          for (const auto& f : std::filesystem::directory_iterator(package.path() / "urdf", scan))
            if (f.path().extension() == ".urdf") found.push_back(f.path().string());
      if (rc.package_path.empty()) rc.package_path.push_back(shared.string());
    }
    std::sort(found.begin(), found.end());
    rc.robots.insert(rc.robots.end(), found.begin(), found.end());
  }
  std::error_code ec;
  std::filesystem::create_directories(config.out_dir, ec);
  if (ec) return Fail(Status::IoError("--out " + config.out_dir + ": " + ec.message()));
  if (!config.images_dir.empty()) std::filesystem::create_directories(config.images_dir, ec);
  if (ec) return Fail(Status::IoError("--images " + config.images_dir + ": " + ec.message()));
  auto robot = LoadRobot(args.robot);
  if (!robot.ok()) return Fail(robot.status());
  auto wanted = [&](const char* name) { return args.only.empty() || args.only.find(name) != std::string::npos; };

  const auto t0 = std::chrono::steady_clock::now();
  bench::Tables tables;
  tables.notes.push_back("robot: " + robot->name() + (args.robot.urdf.empty() ? " (built-in)" : " (" + args.robot.urdf + ")"));
  if (wanted("sweep"))
    if (auto st = bench::SweepExperiment(*robot, config, &tables); !st.ok()) return Fail(st.WithContext("sweep"));
  if (wanted("perturb"))
    if (auto st = bench::PerturbExperiment(*robot, config, &tables); !st.ok()) return Fail(st.WithContext("perturbations"));
  if (wanted("scenes"))
    if (auto st = bench::ScenesExperiment(*robot, config, &tables); !st.ok()) return Fail(st.WithContext("scenes"));
  // Only when asked for: it simulates cells of every robot with both meshers (minutes).
  if (args.only.find("robustness") != std::string::npos)
    if (auto st = bench::RobustnessExperiment(config, &tables); !st.ok()) return Fail(st.WithContext("robustness"));
  if (args.only.find("auto") != std::string::npos)
    if (auto st = bench::AutoExperiment(config, &tables); !st.ok()) return Fail(st.WithContext("auto"));
  // Only when asked for: minutes of simulated streams per robot.
  if (args.only.find("track") != std::string::npos)
    if (auto st = bench::TrackExperiment(config, &tables); !st.ok()) return Fail(st.WithContext("track"));
  const double minutes = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / 60;
  tables.notes.push_back(fmt::format("{} runs in {:.1f} min with {} parallel job(s)", tables.runs.size(), minutes, config.jobs));
  if (config.quick) tables.notes.push_back("--quick: a subset (small configuration only, fewer cells, seeds and parameter sets)");
  if (auto st = bench::WriteReport(config, tables, args.command_line); !st.ok()) return Fail(st);
  spdlog::info("bench: {} runs in {:.1f} min", tables.runs.size(), minutes);
  return kExitOk;
}

}  // namespace

void AddBenchCommand(CLI::App& app, int* exit_code) {
  auto args = std::make_shared<BenchArgs>();
  CLI::App* cmd = app.add_subcommand("bench", "Reproduce the paper's experiments on simulated cells with ground truth");
  AddRobotOptions(*cmd, args->robot);
  cmd->add_option("--out", args->out, "Directory for results.md, CSV files and plots")->required();
  cmd->add_option("--methods", args->methods, "Registration methods to sweep and compare, comma-separated")->capture_default_str();
  cmd->add_option("--scene-methods", args->scene_methods, "Methods run on every kind of scene (default: --methods)");
  cmd->add_option("--perturb-methods", args->perturb_methods, "Methods for the seed perturbations (Table III)")->capture_default_str();
  cmd->add_flag("--quick", args->quick, "A small subset (about two minutes on two cores)");
  cmd->add_flag("--no-big", args->no_big, "Skip the paper's big configuration (256,000 samples)");
  cmd->add_option("--jobs", args->jobs, "Registrations run in parallel (1: clean per-run times and memory)")
      ->check(CLI::Range(1, 64))->capture_default_str();
  cmd->add_option("--rng-seed", args->rng_seed, "Seed of the simulated cells")->capture_default_str();
  cmd->add_option("--scene-kinds", args->scene_kinds,
                  "Scenes experiment: kinds of cell (default, near-table, clutter, second-robot, empty)")
      ->delimiter(',')->check(CLI::IsMember({"default", "near-table", "clutter", "second-robot", "empty"}));
  cmd->add_option("--scene-size", args->scene_size, "Scenes experiment: small or big configuration")
      ->check(CLI::IsMember({"small", "big"}))->capture_default_str();
  cmd->add_option("--scene-cells", args->scene_cells, "Scenes experiment: cells per kind")->check(CLI::Range(1, 1000))->capture_default_str();
  cmd->add_option("--scene-seeds", args->scene_seeds, "Scenes experiment: seeds per cell")->check(CLI::Range(1, 1000))->capture_default_str();
  cmd->add_flag("--seed-any-yaw", args->seed_any_yaw, "Scenes experiment: seeds with any yaw error");
  cmd->add_option("--seed-max-offset", args->seed_max_offset,
                  "Scenes experiment: seeds' horizontal error uniform in a disc of this radius, m (0: user-like)")
      ->check(CLI::Range(0.0, 3.0));
  cmd->add_flag("--walk-any-side", args->walk_any_side,
                "Scenes experiment: each cell's robot turned at random, so the user maps any side of it (default: its front)");
  cmd->add_flag("--varied-walk", args->varied_walk,
                "Scenes experiment: each cell's user walks a path of their own: arc 40 deg either side of --walk-arc, "
                "centre within 30 deg, 1.5-2.4 m off, eyes 1.5-1.8 m high, 16-32 views, 0.1 m wander (default: the "
                "simulator's regular arc)");
  cmd->add_flag("--head-path", args->head_path,
                "Scenes, robustness and auto experiments: each request sends where its cell's (room's) user walked "
                "while mapping, as a HoloLens app can (RegisterRequest.head_path)");
  cmd->add_option("--walk-arc", args->walk_arc_deg,
                  "Scenes experiment: the arc the simulated user walks round the robot, deg (default 220)")
      ->check(CLI::Range(30.0, 360.0));
  cmd->add_option("--pose-jitter", args->pose_jitter,
                  "Scenes experiment: head-tracking error sigma, m (default 0.004, 0.3 deg; 0: a perfectly tracked headset)")
      ->check(CLI::Range(0.0, 0.1));
  cmd->add_option("--tracking-error", args->tracking_error,
                  "Scenes experiment: the head-tracking error sigma arref-icp assumes, m, with 75 deg per m as "
                  "--pose-jitter (default 0.004, 0.3 deg; 0: equal weights in its last polish)")
      ->check(CLI::Range(0.0, 0.1));
  cmd->add_option("--images", args->images,
                  "Scenes experiment: write a PNG of each cell's first result per method into this folder "
                  "(arref register --image's picture)");
  cmd->add_option("--only", args->only,
                  "Run only these experiments: sweep, perturb, scenes, robustness, auto, track (comma-separated; "
                  "robustness, auto and track run only when named)");
  cmd->add_option("--robots", args->robots,
                  "Robustness: robot URDFs, comma-separated, 'builtin' for the built-in robot (default: builtin and "
                  "every URDF under ../shared/robots/*/urdf/, which is also the default --package-path)")
      ->delimiter(',');
  cmd->add_option("--meshers", args->meshers, "Robustness: meshers of the headset's mesh (own, open3d)")
      ->delimiter(',')->check(CLI::IsMember({"own", "open3d"}));
  cmd->add_option("--seed-families", args->seed_families, "Robustness: seed families (user, cube, any-yaw, default; truth: the true pose, a diagnostic of the fit's own error)")
      ->delimiter(',')->check(CLI::IsMember({"default", "user", "cube", "any-yaw", "truth"}));
  cmd->add_option("--robust-methods", args->robust_methods, "Robustness: registration methods")->capture_default_str();
  cmd->add_option("--split", args->split,
                  "Robustness: dev (without --heldout-robot) or heldout (every robot; cells and seeds from a stream of "
                  "their own: look at it once, at the end)")
      ->check(CLI::IsMember({"dev", "heldout"}))->capture_default_str();
  cmd->add_option("--heldout-robot", args->heldout_robot,
                  "Robustness: the robot the dev split leaves out (part of its name or URDF path)")->capture_default_str();
  cmd->add_option("--robust-cells", args->robust_cells, "Robustness: cells per robot and mesher (--quick: 1)")
      ->check(CLI::Range(1, 1000))->capture_default_str();
  cmd->add_option("--robust-seeds", args->robust_seeds, "Robustness: seeds per family and cell (--quick: 1)")
      ->check(CLI::Range(1, 1000))->capture_default_str();
  cmd->add_option("--robust-without", args->robust_without,
                  "Robustness and auto: headset errors to take out of every cell or room, to measure what each costs "
                  "(view-jitter, surface-errors, depth-noise, patches, quantisation)")
      ->delimiter(',')->check(CLI::IsMember({"view-jitter", "surface-errors", "depth-noise", "patches", "quantisation"}));
  cmd->add_option("--mapping-motion", args->mapping_motion,
                  "Robustness: joints that swing while the cell is mapped, so the map smears the arm (none; wrist: the "
                  "last half of the actuated joints; arm: all but the first; all)")
      ->check(CLI::IsMember({"none", "wrist", "arm", "all"}))->capture_default_str();
  cmd->add_option("--moving-fit", args->moving_fit,
                  "Robustness, with --mapping-motion: what the fit rests on (auto: the product's choice; whole: the "
                  "whole model at the final joints; unmoved: the links no moving joint carries)")
      ->check(CLI::IsMember({"auto", "whole", "unmoved"}))->capture_default_str();
  cmd->add_flag("--robust-pedestals", args->robust_pedestals,
               "Robustness: stand the arm on a 0.2-0.7 m pedestal in half the cells, and always when it reaches "
               "below its base (default: every arm on the floor, as draws measured before it)");
  cmd->add_flag("--robust-own-voxels", args->robust_own_voxels,
               "Robustness: fuse each own-mesher cell at a voxel drawn in 2-6 cm, as the Open3D device's (default: "
               "3.46 cm, the 1,000 triangles per m^3 of the paper, as draws measured before it)");
  cmd->add_option("--auto-methods", args->auto_methods,
                  "Auto experiment (seedless, whole rooms; runs only when --only names it): methods, comma-separated")
      ->capture_default_str();
  cmd->add_option("--auto-rooms", args->auto_rooms, "Auto experiment: rooms per robot, arm count (0, 1, 2) and mesher")
      ->check(CLI::Range(1, 1000))->capture_default_str();
  cmd->add_option("--auto-arms", args->auto_arms,
                  "Auto experiment: the arm counts run, comma-separated (0: rooms without the requested arm)")
      ->delimiter(',')->check(CLI::Range(0, 2));
  cmd->add_flag("--auto-truth-seeds", args->auto_truth_seeds,
                "Auto experiment: seeded methods (e.g. arref-icp) start at each requested arm's true pose, one request "
                "per arm, instead of the map's centre: the fit's own error on a room's map");
  cmd->add_option("--track-kinds", args->track.kinds, "Track: frame kinds (long-throw, ahat)")
      ->delimiter(',')->check(CLI::IsMember({"long-throw", "ahat"}));
  cmd->add_option("--track-streams", args->track.streams, "Track: streams per robot and frame kind (0: only the long streams)")
      ->check(CLI::Range(0, 100))->capture_default_str();
  cmd->add_option("--track-seconds", args->track.seconds, "Track: seconds per stream")->check(CLI::Range(2.0, 3600.0))->capture_default_str();
  cmd->add_option("--track-baseline-frames", args->track.baseline_frames,
                  "Track: frames per long-throw stream also registered the one-shot way (PCL ICP), 0: none")
      ->check(CLI::Range(0, 1000))->capture_default_str();
  cmd->add_option("--track-long-minutes", args->track.long_minutes, "Track: minutes of the long stream (drift, memory; 0: none)")
      ->check(CLI::Range(0.0, 120.0))->capture_default_str();
  cmd->add_option("--track-long-fps", args->track.long_fps, "Track: frame rate of the long stream")
      ->check(CLI::Range(1.0, 60.0))->capture_default_str();
  cmd->add_option("--track-long-streams", args->track.long_streams, "Track: long streams per robot (seeds)")
      ->check(CLI::Range(1, 100))->capture_default_str();
  cmd->add_option("--track-flying-pixels", args->track.flying_pixel_rate,
                  "Track: share of the pixels on depth edges that return a depth between the edge's sides (0: none)")
      ->check(CLI::Range(0.0, 1.0))->capture_default_str();
  cmd->add_option("--track-depth-noise", args->track.depth_noise_fraction,
                  "Track: depth noise sigma as a fraction of range (0: the frame kind's own, 0.01 long-throw, 0.003 AHAT)")
      ->check(CLI::Range(0.0, 0.2))->capture_default_str();
  cmd->add_option("--track-pose-latency-ms", args->track.pose_latency_ms,
                  "Track: the camera pose is head tracking's this long after the exposure (ms; 0: at it)")
      ->check(CLI::Range(-1000.0, 1000.0))->capture_default_str();
  cmd->add_option("--track-declared-latency-ms", args->track.declared_latency_ms,
                  "Track: the camera pose latency the sender declares to the tracker (ms; 0: none said)")
      ->check(CLI::Range(0.0, 1000.0))->capture_default_str();
  cmd->callback([args, exit_code, cmd] {
    args->command_line = "arref bench";
    for (const auto& o : cmd->get_options())
      if (o->count() > 0 && o->get_name() != "--help")
        args->command_line += " " + o->get_name() + (o->get_expected_min() > 0 ? " " + o->as<std::string>() : "");
    *exit_code = Run(*args);
  });
}

}  // namespace arref::cli
