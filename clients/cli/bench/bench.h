// `arref bench`: the paper's experiments (Puljiz et al. 2019, Sec. V) on simulated cells with
// ground truth. Cells and runs, statistics, the three experiments and the report.
#pragma once

#include <cmath>
#include <memory>

#include <map>
#include <string>
#include <vector>

#include "arref/pipeline/pipeline.h"
#include "arref/sim/cell_simulator.h"

namespace arref::bench {

constexpr double kSuccessAddM = 0.010;  // success = ADD <= 10 mm
constexpr double kWrongAddM = 0.020;    // a result this far off is wrong (and must never be OK)
constexpr double kMeshGoodM = 0.005;    // a cell whose mesh moved the robot less than this


// How the scenes experiment's cells and seeds depart from the simulator's defaults.
struct CellVariation {
  sim::SeedNoise seed_noise;
  bool walk_any_side = false;  // each cell's robot turned at random: the user maps any side of it
  double walk_arc_deg = 0.0;   // > 0: the arc the simulated user walks (default: the simulator's)
  // Each cell's user walks a path of their own (arc, centre, distance, eye height, views, and a
  // wander off the arc) instead of the simulator's regular arc, whose eyes the expected
  // surfaces' eyes match.
  bool varied_walk = false;
  double pose_jitter_m = -1;   // >= 0: the head-tracking error (sim::SetPoseJitter; default: the simulator's)
};

// The robustness experiment: robots x meshers x seed families.
struct RobustnessConfig {
  std::vector<std::string> robots;        // URDF paths; "builtin" for the built-in robot
  std::vector<std::string> package_path;  // for package:// URIs
  std::vector<std::string> meshers = {"own", "open3d"};
  std::vector<std::string> seed_families = {"user", "cube", "any-yaw"};
  std::vector<std::string> methods = {"arref-icp"};
  // dev: the development split, without the held-out robot; heldout: every robot, cells and
  // seeds from a random stream of their own (to be looked at once, at the end).
  std::string split = "dev";
  std::string heldout_robot = "sia10d";  // matched against the robot's name and URDF path
  int cells = 4;  // per robot and mesher (the same cells for every mesher)
  int seeds = 2;  // per seed family and cell
  // Headset errors taken out of every cell (sim::LeaveOutErrors), to measure what each costs.
  std::vector<std::string> without;
  // The robot working while the cell is mapped (sim::MappingMotion): none; wrist (the last half
  // of the actuated joints swing); arm (all but the first); all. Amplitude and swings drawn per cell.
  std::string motion = "none";
  // What a fit on such a map rests on: auto (the product's choice, MovingFitLinks), whole (the
  // whole model at the final joints), unmoved (only the links no moving joint carries).
  std::string moving_fit = "auto";
  // Arms on pedestals: half the cells stand the robot on one 0.2-0.7 m high, and an arm that
  // reaches below its base always on one that clears its reach. Off by default, so that draws
  // stay comparable with those measured before it existed.
  bool pedestals = false;
  // The own mesher at a voxel drawn per cell, 2-6 cm as the Open3D device's (sim::DeviceVariation),
  // instead of the 3.46 cm that 1,000 triangles per m^3 gives: the expected surface is then
  // fitted on coarse and fine meshes of its own kind too. Off by default, as pedestals.
  bool own_voxels = false;
};

// The tracking experiment: robots as RobustnessConfig's, with its split.
struct TrackConfig {
  std::vector<std::string> kinds = {"long-throw", "ahat"};
  int streams = 2;            // per robot and frame kind
  double seconds = 20.0;      // per stream
  int baseline_frames = 8;    // per long-throw stream, the one-shot baseline
  double long_minutes = 10.0; // the long stream (0: none)
  double long_fps = 5.0;      // at the long-throw camera's real rate, to keep it affordable
  int long_streams = 1;       // long streams per robot, each from a seed of its own
  // What a real device adds that the default streams leave out (sim::TrackSimOptions): mixed
  // pixels on depth edges, and a camera pose stamped off the exposure.
  double flying_pixel_rate = 0.0;
  double pose_latency_ms = 0.0;
  // The depth's noise sigma as a fraction of range (0: the frame kind's own, 1 % long-throw and
  // 0.3 % AHAT): a sensor noisier than the tracker's tolerances were set on.
  double depth_noise_fraction = 0.0;
  double declared_latency_ms = 0.0;  // the latency the sender tells the tracker (TrackRequest)
};

struct Config {
  std::vector<std::string> methods;          // swept (Tables I, II)
  std::vector<std::string> perturb_methods;  // Table III
  std::vector<std::string> scene_methods;    // every kind of scene
  std::string out_dir;
  bool quick = false;
  bool big = true;  // also the paper's "big" configuration
  int jobs = 1;
  std::uint64_t rng_seed = 1;
  // The scenes experiment (the engine comparison): which cells, how many, and how the seeds err.
  std::vector<std::string> scene_kinds = {"default", "near-table", "clutter", "second-robot"};
  std::string scene_size = "small";
  int scene_cells = 2;  // per kind
  int scene_seeds = 3;  // per cell
  CellVariation variation;
  bool head_path = false;  // each request sends where its cell's user walked (RegistrationOptions::head_path_world)
  // >= 0: the head-tracking error arref-icp assumes (ArrefIcpParams::tracking_error), m, with
  // 75 degrees per metre as sim::SetPoseJitter; 0: equal weights. Default: the method's own.
  double tracking_error_m = -1;
  RobustnessConfig robustness;
  // Non-empty: the scenes experiment writes a picture of each cell's first seed's result per
  // method there (scenes_<method>_<kind>_<cell>.png).
  std::string images_dir;
  // The auto experiment (seedless, whole rooms): its robots, meshers and split are robustness's.
  std::vector<std::string> auto_methods = {"arref-auto", "sliding-box-shot", "super4pcs", "fpfh-ransac"};
  int auto_rooms = 2;  // per robot, arm count (0, 1, 2) and mesher
  std::vector<int> auto_arms = {0, 1, 2};  // the arm counts run (0 alone: only rooms without the arm)
  // Seeded methods start at each requested arm's true pose instead of the map's centre: a
  // diagnostic of the fit's own error in rooms (robustness's truth seeds, for rooms).
  bool auto_truth_seeds = false;
  TrackConfig track;
};

// A simulated cell with everything a run needs.
struct Cell {
  std::string kind;  // default, near-table, clutter, second-robot, empty (no robot)
  std::string size;  // small, big
  int index = 0;
  sim::SimulatedCell sim;
  TriangleMesh scene_world;
  std::shared_ptr<const RobotSide> robot;  // samples and the expected headset surface
  TriangleMesh robot_base;                 // the posed robot in its base frame, for pictures (MakeCells)
  // RegistrationOptions::map_not_as_posed for requests on this cell (the joints moved while it
  // was mapped, as CellRobotSide judged it).
  std::string map_not_as_posed;
};

// One registration against ground truth.
struct Run {
  std::string experiment, method, size, params, scene_kind;
  int cell = 0, seed = 0;
  double seed_yaw_deg = 0;        // Table III perturbation
  Vec3 seed_offset_m = Vec3::Zero();
  std::string perturbation;       // "", "none", "rotation", "translation"
  std::string robot, mesher, seed_family;  // robustness experiment
  bool ok = false;
  std::string status;  // the result's OK / LOW_CONFIDENCE / FAILED
  std::string error;
  double rms_m = 0, add_m = 0, translation_m = 0, rotation_deg = 0;
  double vertical_m = 0, horizontal_m = 0;  // the translation error's parts (PoseError)
  std::map<std::string, double> stage_ms;
  int iterations = 0;  // the method's ICP iterations; 0 where it does not report them (Open3D 0.16)
  double total_ms = 0;
  double peak_mb = 0;
  double mesh_error_m = -1;  // the cell's SimulatedCell::mesh_error_add_m (-1: not measured)
  // The fit's ADD against where the mesh put the robot (SimulatedCell::T_world_base_mesh): the
  // method's own error, the mesh's taken out (-1: not measured).
  double method_error_m = -1;
  double voxel_m = 0;        // robustness: the voxel the cell's headset mesh was fused at (SimulatedCell::voxel_m)
  FitPrecision precision;    // the result's own (invalid where none was measured)
  std::string stages;        // the result's stages_run, ';'-separated
};

// A run to do: which cell, seed pose and options.
struct Job {
  Run run;  // labels filled in; results filled by Execute
  const Cell* cell = nullptr;
  Iso3 T_world_seed = Iso3::Identity();
  RegistrationOptions options;
  bool seed_only = false;  // measure the seed itself (the paper's "user guess" row)
  std::string image_path;  // non-empty: a picture of the result goes there (result_image.h)
};

Result<std::vector<Cell>> MakeCells(const RobotModel& robot, const std::vector<std::string>& kinds, const std::string& size,
                                    int cells_per_kind, int seeds_per_cell, std::uint64_t rng_seed,
                                    const CellVariation& variation = {});
// Runs every job (in parallel when jobs > 1) and returns their runs in order.
std::vector<Run> Execute(std::vector<Job>& jobs, int parallel_jobs);

// Statistics of a group of runs: one row of a table.
struct Row {
  std::map<std::string, std::string> labels;  // e.g. method, size, params
  std::size_t runs = 0, errors = 0, segmentation_flags = 0;
  double success = 0;  // share of all runs with ADD <= 10 mm
  double within_20mm = 0;
  double status_ok = 0;           // share of all runs whose result said OK
  std::size_t wrong_ok = 0;       // runs that said OK with ADD > 20 mm (or with no robot there)
  double rms_mean_mm = 0, rms_min_mm = 0, rms_max_mm = 0, rms_std_mm = 0;
  double add_median_mm = 0, add_p95_mm = 0, translation_median_mm = 0, rotation_median_deg = 0;
  double register_median_ms = 0, total_median_ms = 0, mls_median_ms = 0;
  double iteration_median_ms = 0;  // register time / iterations, median over the runs that report them
  double peak_mb = 0;
  double mesh_error_median_mm = std::nan("");  // over runs whose cell measured it
  double method_error_median_mm = std::nan("");  // Run::method_error_m, the same runs
  std::size_t mesh_good_runs = 0;               // runs on cells whose mesh error is under 5 mm
  double success_mesh_good = 0;                 // share of those within ADD 10 mm
  // The results' own expected error (Result.expected_error_m), over the runs that gave one, and
  // the share of those whose ADD lay within twice it: how honest the figure is.
  double expected_error_median_mm = std::nan("");
  double within_twice_expected = std::nan("");
};
Row Summarise(const std::vector<const Run*>& runs, std::map<std::string, std::string> labels);

// The experiments: each returns its runs (every one also goes to runs.csv).
struct Tables {
  std::vector<Row> table1, table2, table3, scenes, robustness;
  std::vector<Run> runs;
  std::vector<std::string> notes;
};
Status SweepExperiment(const RobotModel& robot, const Config& config, Tables* tables);      // Tables I, II
Status PerturbExperiment(const RobotModel& robot, const Config& config, Tables* tables);    // Table III + plots
Status ScenesExperiment(const RobotModel& robot, const Config& config, Tables* tables);     // methods x scene kinds
// The robots of --robots (`builtin` for the built-in one), each once; the development split
// (keep_heldout false) leaves --heldout-robot out. `experiment` names the caller in messages.
struct BenchRobot {
  std::string label;  // the robot's name
  std::string urdf;
  std::shared_ptr<const RobotModel> model;
};
Result<std::vector<BenchRobot>> LoadBenchRobots(const RobustnessConfig& rc, bool keep_heldout, const std::string& experiment);
Status RobustnessExperiment(const Config& config, Tables* tables);  // robots x meshers x seed families
Status AutoExperiment(const Config& config, Tables* tables);        // seedless, whole rooms (auto.cpp)
Status TrackExperiment(const Config& config, Tables* tables);       // robots x frame kinds, to track.md

// One bench cell of `kind` (as MakeCells makes them) simulated from `seed` by `mesher`; the
// model side is shared when given (the same robot and joints), else built.
// rc: the headset errors taken out (without), the joints' motion while mapping and what the fit
// rests on then (motion, moving_fit), the pedestals and the own mesher's voxel (own_voxels).
Result<Cell> MakeCell(const RobotModel& robot, const std::string& kind, int index, std::uint64_t seed, sim::Mesher mesher,
                      std::shared_ptr<const RobotSide> robot_side, const RobustnessConfig& rc);

Status WriteReport(const Config& config, const Tables& tables, const std::string& command_line);

}  // namespace arref::bench
