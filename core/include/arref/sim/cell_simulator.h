// Simulated robot cells with ground truth: what a HoloLens would map around a robot, and
// where the robot really is. Used by tests, the demo, the mock headset and the benchmarks.
#pragma once

#include <cstdint>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/robot/joint_motion.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/base/status.h"

namespace arref::sim {

// The robot working while the user maps it: the moving joints swing round their final values
// (CellOptions::joints) and come to them at the last view, so the map holds the moving links
// smeared over the poses they passed through while the request sees the final joint state.
struct MappingMotion {
  std::vector<std::string> joints;  // actuated joints that move; empty: the robot stands still
  double amplitude_rad = 0.5;       // how far either side of the final value (clamped into limits)
  double cycles = 1.5;              // swings over the walk
};

// What stands in the cell. Lengths in metres; the robot base is at the cell origin.
struct CellOptions {
  JointValues joints;               // robot pose; unnamed joints are 0
  bool robot_present = true;        // false: an empty cell (where a registration must not say OK)
  double pedestal_height_m = 0.0;   // 0: robot on the floor
  // The robot's heading in the cell. The walker circles the cell's +x side, so this sets which
  // side of the robot gets mapped (0: its front).
  double base_yaw_deg = 0.0;
  bool walls = true;                // two walls meeting behind the robot
  bool table = true;                // a table beside the robot
  double table_gap_m = 0.2;         // table edge to robot base footprint (or pedestal), 0.05-0.4 typical
  int clutter_boxes = 4;            // random boxes on the floor and table
  bool second_robot = false;        // another robot of the same model nearby
  double second_robot_distance_m = 1.6;
  MappingMotion motion;
};

// How the user walks and what the depth sensor sees (HoloLens long-throw-like).
struct ScanOptions {
  int views = 24;                   // viewpoints along the path
  double path_arc_deg = 220.0;      // the path covers this much of the circle: the rest is never seen
  double path_radius_m = 1.9;       // distance of the walker from the robot base
  double eye_height_m = 1.65;
  double path_center_deg = 0.0;     // the arc's middle, from the cell's +x
  // A person walks no circle: sigma of each view's departure from the arc, in radius and eye
  // height (a third of it), and its azimuth moves up to 40 % of the spacing. 0: exactly on it.
  double path_wander_m = 0.0;
  int image_width = 320;
  int image_height = 288;
  double fov_horizontal_deg = 75.0;
  double max_range_m = 4.0;
  double depth_noise_m = 0.008;     // sigma along the ray
  double pose_jitter_m = 0.004;     // sigma of the per-view head position error
  double pose_jitter_deg = 0.3;     // sigma of the per-view head orientation error
};

// Head-tracking error as one knob: sigma_m of position, and 75 deg per metre of orientation
// (the defaults' 0.3 deg at 4 mm). The fused mesh is distorted by it, so it bounds how close
// any registration can come to the truth (docs/engine.md, "What limits accuracy").
void SetPoseJitter(ScanOptions* scan, double sigma_m);

// How the depth images become the headset's mesh.
//  kOwn:    core's TSDF and surface nets (tsdf.h), one fusion, split on a fixed grid.
//  kOpen3d: Open3D's TSDF, marching cubes and quadric decimation, with a device's variations
//           (DeviceVariation). arref-icp predicts the headset's mesh with core's own TSDF, so
//           a bench on kOwn meshes alone flatters it; kOpen3d shares none of that code.
enum class Mesher { kOwn, kOpen3d };
const char* MesherName(Mesher mesher);  // "own", "open3d"
Result<Mesher> ParseMesher(const std::string& name);
bool MesherAvailable(Mesher mesher);  // kOpen3d needs arref_sim built with Open3D

// What differs between one headset's mesh of a cell and another's (HoloLens spatial mapping,
// as set through MRTK's spatial awareness observer): drawn per cell by DrawDeviceVariation,
// each quantity from its own random stream, so adding one leaves the others as they were.
struct DeviceVariation {
  double voxel_m = 0.03;              // TSDF voxel edge
  double triangles_per_m3 = 1000.0;   // decimation target per m^3 of each surface cube
  double quantisation_m = 0.001;      // vertex positions rounded to this grid in each surface's frame
  double surface_size_m = 1.5;        // the mesh comes as cubes of this edge (world grid)
  int surface_updates = 4;            // each surface is meshed at one of these times near the walk's end
  double surface_error_max_m = 0.01;  // per surface: a rigid head-pose error up to this (uniform)
  double surface_error_max_deg = 0.5;
  int missing_patches = 3;            // dark or shiny spots that return no depth
  double patch_radius_max_m = 0.2;    // their radius, uniform in [a quarter of this, this]
  double depth_noise_m = 0.008;       // replaces scan.depth_noise_m
  double walk_arc_deg = 220.0;        // replaces scan.path_arc_deg
  double walk_distance_m = 1.9;       // replaces scan.path_radius_m (kept clear of the arm's reach)
};
// The ranges: voxel 2-6 cm; 400-2,000 triangles per m^3 (about MRTK's Medium to Fine levels of
// detail; Puljiz et al. 2019 used 1,000); quantisation 0.03-4 mm; surfaces 1-2 m; 2-6 update times; errors up to
// 0-1 cm and 0-0.5 deg; 0-6 patches of up to 5-30 cm; depth noise 4-12 mm; walks of 90-360
// deg at 1-3 m.
DeviceVariation DrawDeviceVariation(std::uint64_t rng_seed);
// Takes some of a headset's errors out of a cell simulated from rng_seed, to measure what each
// costs: "view-jitter" (each view's tracking error), "surface-errors" (kOpen3d: each surface's
// head-pose error), "depth-noise" (down to 1 mm), "patches" (kOpen3d: no missing patches),
// "quantisation" (kOpen3d: none). The rest of the device's variation stays as drawn.
struct SimOptions;
Status LeaveOutErrors(const std::vector<std::string>& errors, std::uint64_t rng_seed, SimOptions* options);

// TSDF fusion of the depth images and extraction of a coarse mesh.
struct FusionOptions {
  Mesher mesher = Mesher::kOwn;
  // kOpen3d: the device's variation; unset, drawn from the cell's seed (DrawDeviceVariation).
  // triangles_per_m3, voxel_m, truncation_voxels and surface_chunk_m below are kOwn's.
  std::optional<DeviceVariation> device;
  double triangles_per_m3 = 1000.0;  // HoloLens density setting; sets the voxel size when voxel_m == 0
  double voxel_m = 0.0;              // explicit voxel edge; 0 = derive from triangles_per_m3
  double truncation_voxels = 3.0;     // TSDF band; widened to 6 sigma of scan.depth_noise_m if that is more
  double surface_chunk_m = 1.0;      // split into HoloLens-like surfaces on this grid
  double crop_radius_m = 3.0;        // fuse only within this distance of the robot base
};

// Families of seeds (a user's rough placement of the seed cube at the robot base):
//  kDefault: the simulator's own user-like seeds (the fields of SeedNoise below).
//  kUser:    wider user-like: 0.1-0.3 m off horizontally, +-0.3 m in height round the base
//            (below it too: the cube placed at the floor, the base on a pedestal), yaw ~15 deg.
//  kCube:    uniform in a cube +-0.5 m round the base in x, y and z, yaw ~15 deg.
//  kAnyYaw:  kUser's position with any yaw.
//  kTruth:   the true pose itself. Not a user's: a diagnostic that starts the search at the answer,
//            so what is left is the fit's own error on that mesh, not the search's.
enum class SeedFamily { kDefault, kUser, kCube, kAnyYaw, kTruth };
const char* SeedFamilyName(SeedFamily family);  // "default", "user", "cube", "any-yaw", "truth"
Result<SeedFamily> ParseSeedFamily(const std::string& name);

// A user's rough placement of the seed cube at the robot base.
struct SeedNoise {
  SeedFamily family = SeedFamily::kDefault;  // the other fields are kDefault's
  double horizontal_sigma_m = 0.07;  // per axis: ~0.1 m typical horizontal error
  double vertical_max_m = 0.3;       // uniform in [0, vertical_max_m] above the base
  double yaw_sigma_deg = 15.0;
  bool any_yaw = false;              // yaw error uniform over the full circle instead
  double max_horizontal_m = 0.0;     // > 0: horizontal offset uniform in a disc of this radius instead
};

struct SimOptions {
  CellOptions cell;
  ScanOptions scan;
  FusionOptions fusion;
  SeedNoise seed_noise;
  int seed_count = 10;
};

SimOptions SmallPreset();  // the paper's "small": 1,000 triangles per m^3 (16,000 scene samples)
SimOptions BigPreset();    // the paper's "big": 1,240,000 triangles per m^3 (256,000 samples)

// An object placed in the cell, for tests and reports: its axis-aligned bounds in the cell
// frame (z up, floor at z = 0, robot base above the origin).
struct Prop {
  std::string kind;  // "robot_footprint", "pedestal", "table", "wall", "clutter", "second_robot"
  Aabb bounds_cell;
};

struct SimulatedCell {
  std::vector<Surface> surfaces;      // in the internal frame; world via T_world_surface
  Iso3 T_world_base = Iso3::Identity();  // ground truth, random gravity-aligned world frame
  JointValues joints;                 // complete joint values of the robot
  // With CellOptions::motion: each moving joint's least and most value over the views (what a
  // joint state stream sent while the user mapped); empty when the robot stood still.
  JointRanges joints_while_mapping;
  std::vector<Iso3> seeds;            // T_world_seed: user-like guesses of T_world_base
  TriangleMesh truth_world;           // exact scene geometry (robot + props) in world
  double voxel_m = 0.0;               // voxel edge used for fusion
  Iso3 T_world_cell = Iso3::Identity();  // the cell layout frame (floor under the base) in world
  std::vector<Prop> props;            // what was placed where, in the cell frame
  // Where head tracking put the headset at each view (the poses the mesh was fused at), in
  // world: what an app can log while its wearer maps the robot.
  std::vector<Vec3> head_path_world;
  Mesher mesher = Mesher::kOwn;
  DeviceVariation device;             // kOpen3d: the variation this cell's mesh was made with
  // How far the headset's own errors move the robot in the mesh: each view's tracking error
  // (averaged over the views that saw each part, as the fusion does) and, kOpen3d, each
  // surface's head-pose error; the ADD of the gravity-aligned rigid motion that best explains,
  // point to plane, where they put the robot's seen surface. What a fit against the true pose
  // cannot beat. -1 where not measured (a robot that cannot be posed).
  double mesh_error_add_m = -1.0;
  // Where that motion put the base (world): the pose a fit that explains the mesh perfectly
  // lands at, so a fit's ADD against it is the method's own error. None where not measured.
  std::optional<Iso3> T_world_base_mesh;
};

Result<SimulatedCell> SimulateCell(const RobotModel& robot, const SimOptions& options,
                                   std::uint64_t rng_seed);

// Seeds drawn like a user's placement around the true base pose.
std::vector<Iso3> DrawSeeds(const Iso3& T_world_base, const SeedNoise& noise, int count,
                            std::mt19937_64& rng);

}  // namespace arref::sim
