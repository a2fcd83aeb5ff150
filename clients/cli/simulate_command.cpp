// `arref simulate`: a simulated robot cell with ground truth, as a mesh file and a truth JSON.
#include <spdlog/spdlog.h>

#include <nlohmann/json.hpp>

#include "arref/sim/cell_simulator.h"
#include "cli_common.h"
#include "commands.h"

namespace arref::cli {
namespace {

struct SimulateArgs {
  RobotArgs robot;
  std::string mesh_out = "scene.ply";
  std::string truth_out = "truth.json";
  std::string truth_mesh_out;
  std::string preset = "small";
  std::string frame = "ros";
  std::uint64_t rng_seed = 1;
  int seeds = 10;
  double table_gap = -1;
  bool no_table = false;
  bool no_walls = false;
  int clutter = -1;
  bool second_robot = false;
  double pedestal = 0;
  double base_yaw_deg = 0;
  bool no_robot = false;
  bool seed_any_yaw = false;
  double seed_max_offset = 0;
  double depth_noise = -1;
  double pose_jitter = -1;
  std::string mesher = "own";
  std::string seed_family = "default";
};

int Run(const SimulateArgs& args) {
  auto frame = ParseFrameConvention(args.frame);
  if (!frame.ok()) return Fail(frame.status());
  auto robot = LoadRobot(args.robot);
  if (!robot.ok()) return Fail(robot.status());
  auto joints = ParseJoints(args.robot.joints);
  if (!joints.ok()) return Fail(joints.status());

  auto mesher = sim::ParseMesher(args.mesher);
  if (!mesher.ok()) return Fail(mesher.status());
  auto family = sim::ParseSeedFamily(args.seed_family);
  if (!family.ok()) return Fail(family.status());

  sim::SimOptions options = args.preset == "big" ? sim::BigPreset() : sim::SmallPreset();
  options.fusion.mesher = *mesher;
  options.seed_noise.family = *family;
  options.cell.joints = *joints;
  options.cell.table = !args.no_table;
  options.cell.walls = !args.no_walls;
  if (args.table_gap >= 0) options.cell.table_gap_m = args.table_gap;
  if (args.clutter >= 0) options.cell.clutter_boxes = args.clutter;
  options.cell.second_robot = args.second_robot;
  options.cell.pedestal_height_m = args.pedestal;
  options.cell.base_yaw_deg = args.base_yaw_deg;
  options.seed_count = args.seeds;
  options.cell.robot_present = !args.no_robot;
  options.seed_noise.any_yaw = args.seed_any_yaw;
  options.seed_noise.max_horizontal_m = args.seed_max_offset;
  if (args.depth_noise >= 0) options.scan.depth_noise_m = args.depth_noise;
  if (args.pose_jitter >= 0) sim::SetPoseJitter(&options.scan, args.pose_jitter);

  auto cell = sim::SimulateCell(*robot, options, args.rng_seed);
  if (!cell.ok()) return Fail(cell.status().WithContext("simulating the cell"));

  SpatialMesh map;
  for (auto& s : cell->surfaces)
    if (auto st = map.Upsert(s); !st.ok()) return Fail(st.WithContext("simulator produced a bad surface"));
  TriangleMesh mesh = *map.MergedWorld();
  MeshFromRos(mesh, *frame);
  if (auto st = SaveMeshFile(mesh, args.mesh_out); !st.ok()) return Fail(st);
  if (!args.truth_mesh_out.empty()) {
    TriangleMesh exact = cell->truth_world;
    MeshFromRos(exact, *frame);
    if (auto st = SaveMeshFile(exact, args.truth_mesh_out); !st.ok()) return Fail(st);
  }

  nlohmann::json truth;
  truth["frame"] = args.frame;
  truth["robot"] = robot->name();
  truth["preset"] = args.preset;
  truth["rng_seed"] = args.rng_seed;
  truth["T_world_base"] = MatrixToJson(cell->T_world_base);
  truth["base_pose"] = PoseToJson(cell->T_world_base, *frame);
  truth["joints"] = cell->joints;
  truth["seeds"] = nlohmann::json::array();
  for (const auto& seed : cell->seeds) truth["seeds"].push_back(PoseToJson(seed, *frame));
  // Not truth: what the app logs while its wearer maps (`arref register --head-path`).
  truth["head_path"] = PositionsToJson(cell->head_path_world, *frame);
  truth["voxel_m"] = cell->voxel_m;
  // Written only with the new options, so that existing output stays as it was.
  if (*family != sim::SeedFamily::kDefault) truth["seed_family"] = args.seed_family;
  if (*mesher == sim::Mesher::kOpen3d) {
    const sim::DeviceVariation& d = cell->device;
    truth["mesher"] = args.mesher;
    truth["device"] = {{"voxel_m", d.voxel_m},
                       {"triangles_per_m3", d.triangles_per_m3},
                       {"quantisation_m", d.quantisation_m},
                       {"surface_size_m", d.surface_size_m},
                       {"surface_updates", d.surface_updates},
                       {"surface_error_max_m", d.surface_error_max_m},
                       {"surface_error_max_deg", d.surface_error_max_deg},
                       {"missing_patches", d.missing_patches},
                       {"patch_radius_max_m", d.patch_radius_max_m},
                       {"depth_noise_m", d.depth_noise_m},
                       {"walk_arc_deg", d.walk_arc_deg},
                       {"walk_distance_m", d.walk_distance_m}};
  }
  truth["mesh_error_add_m"] = cell->mesh_error_add_m;
  truth["surfaces"] = cell->surfaces.size();
  truth["triangles"] = mesh.triangles.size();
  if (auto st = WriteJsonFile(truth, args.truth_out); !st.ok()) return Fail(st);
  spdlog::info("wrote {} ({} triangles in {} surfaces, voxel {:.3f} m) and {}", args.mesh_out, mesh.triangles.size(),
               cell->surfaces.size(), cell->voxel_m, args.truth_out);
  return kExitOk;
}

}  // namespace

void AddSimulateCommand(CLI::App& app, int* exit_code) {
  auto args = std::make_shared<SimulateArgs>();
  CLI::App* cmd = app.add_subcommand("simulate", "Simulate a robot cell as a headset maps it, with ground truth");
  AddRobotOptions(*cmd, args->robot);
  cmd->add_option("--mesh-out", args->mesh_out, "Scene mesh to write (.ply, .stl or .obj)")->capture_default_str();
  cmd->add_option("--truth-out", args->truth_out, "Ground truth JSON to write")->capture_default_str();
  cmd->add_option("--truth-mesh-out", args->truth_mesh_out,
                  "Also write the exact scene geometry (what the headset's mesh approximates)");
  cmd->add_option("--preset", args->preset, "small (1,000 triangles/m^3) or big (1,240,000)")
      ->check(CLI::IsMember({"small", "big"}))->capture_default_str();
  cmd->add_option("--frame", args->frame, "Convention of the written mesh and poses: ros or unity")
      ->check(CLI::IsMember({"ros", "unity"}))->capture_default_str();
  cmd->add_option("--rng-seed", args->rng_seed, "Random seed (same seed, same scene)")->capture_default_str();
  cmd->add_option("--seeds", args->seeds, "Number of user-like seed poses to draw")->check(CLI::Range(0, 100000));
  cmd->add_option("--table-gap", args->table_gap, "Table edge to robot base, m")->check(CLI::Range(0.0, 5.0));
  cmd->add_flag("--no-table", args->no_table, "No table in the cell");
  cmd->add_flag("--no-walls", args->no_walls, "No walls in the cell");
  cmd->add_option("--clutter", args->clutter, "Number of clutter boxes")->check(CLI::Range(0, 200));
  cmd->add_flag("--second-robot", args->second_robot, "Place a second robot nearby");
  cmd->add_option("--pedestal", args->pedestal, "Pedestal height under the robot, m")->check(CLI::Range(0.0, 3.0));
  cmd->add_option("--base-yaw", args->base_yaw_deg,
                  "Robot heading in the cell, deg: the walker maps the cell's +x side, so this picks the robot's mapped side")
      ->check(CLI::Range(-360.0, 360.0));
  cmd->add_option("--depth-noise", args->depth_noise, "Depth noise sigma along the ray, m (default 0.008)")
      ->check(CLI::Range(0.0, 0.1));
  cmd->add_option("--pose-jitter", args->pose_jitter,
                  "Head pose error sigma, m (default 0.004; rotation jitter scales with it: 0.3 deg at 0.004)")
      ->check(CLI::Range(0.0, 0.1));
  cmd->add_flag("--no-robot", args->no_robot, "Leave the robot out (seeds still point at its place)");
  cmd->add_flag("--seed-any-yaw", args->seed_any_yaw, "Seeds with any yaw error (uniform over the circle)");
  cmd->add_option("--seed-max-offset", args->seed_max_offset,
                  "Seeds' horizontal error uniform in a disc of this radius, m (0: user-like Gaussian)")
      ->check(CLI::Range(0.0, 3.0));
  cmd->add_option("--mesher", args->mesher,
                  "How the headset's mesh is made: own (arref's TSDF and surface nets, which arref-icp also predicts "
                  "with) or open3d (Open3D's TSDF, marching cubes and decimation with a device's variations drawn per "
                  "cell: voxel, density, quantisation, surfaces meshed at their own times with their own pose errors, "
                  "missing patches, depth noise, walk; those override --depth-noise)")
      ->check(CLI::IsMember({"own", "open3d"}))->capture_default_str();
  cmd->add_option("--seed-family", args->seed_family,
                  "Seeds: default (user-like, 0-0.3 m above the base), user (0.1-0.3 m off, +-0.3 m in height, ~15 deg), "
                  "cube (+-0.5 m in x, y and z, ~15 deg) or any-yaw (user with any yaw)")
      ->check(CLI::IsMember({"default", "user", "cube", "any-yaw"}))->capture_default_str();
  cmd->callback([args, exit_code] { *exit_code = Run(*args); });
}

}  // namespace arref::cli
