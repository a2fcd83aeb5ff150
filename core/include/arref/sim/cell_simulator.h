// Simulated robot cells with ground truth: what a HoloLens would map around a robot, and
// where the robot really is. Used by tests, the demo, the mock headset and the benchmarks.
#pragma once

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/base/status.h"

namespace arref::sim {

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

// TSDF fusion of the depth images and extraction of a coarse mesh.
struct FusionOptions {
  double triangles_per_m3 = 1000.0;  // HoloLens density setting; sets the voxel size when voxel_m == 0
  double voxel_m = 0.0;              // explicit voxel edge; 0 = derive from triangles_per_m3
  double truncation_voxels = 3.0;     // TSDF band; widened to 6 sigma of scan.depth_noise_m if that is more
  double surface_chunk_m = 1.0;      // split into HoloLens-like surfaces on this grid
  double crop_radius_m = 3.0;        // fuse only within this distance of the robot base
};

// A user's rough placement of the seed cube at the robot base.
struct SeedNoise {
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
  std::vector<Iso3> seeds;            // T_world_seed: user-like guesses of T_world_base
  TriangleMesh truth_world;           // exact scene geometry (robot + props) in world
  double voxel_m = 0.0;               // voxel edge used for fusion
  Iso3 T_world_cell = Iso3::Identity();  // the cell layout frame (floor under the base) in world
  std::vector<Prop> props;            // what was placed where, in the cell frame
  // Where head tracking put the headset at each view (the poses the mesh was fused at), in
  // world: what an app can log while its wearer maps the robot.
  std::vector<Vec3> head_path_world;
};

Result<SimulatedCell> SimulateCell(const RobotModel& robot, const SimOptions& options,
                                   std::uint64_t rng_seed);

// Seeds drawn like a user's placement around the true base pose.
std::vector<Iso3> DrawSeeds(const Iso3& T_world_base, const SeedNoise& noise, int count,
                            std::mt19937_64& rng);

}  // namespace arref::sim
