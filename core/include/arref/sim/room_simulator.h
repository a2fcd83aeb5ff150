// Simulated rooms with ground truth for seedless referencing: a whole room (up to 10 x 10 x 3 m)
// with walls, tables, shelves and clutter, 0, 1 or 2 arms of the requested model and possibly
// an arm of another model, mapped by a walker who looks round the room and circles every arm.
// Placements are drawn widely (near a wall, beside a table or in the open; on the floor or on a
// pedestal; any heading), so that a method cannot lean on where the simulator puts things.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/sim/cell_simulator.h"

namespace arref::sim {

struct RoomOptions {
  int arms = 1;                    // instances of the requested model: 0, 1 or 2
  bool other_arm = false;          // also one arm of `other` (RoomRobots), a distractor
  bool same_joints = true;         // the requested model's arms share one joint state
  // The room's size is drawn in these ranges (x, y uniform; height uniform).
  double min_side_m = 4.0, max_side_m = 10.0;
  double min_height_m = 2.5, max_height_m = 3.0;
  Mesher mesher = Mesher::kOwn;
  // kOwn: the voxel (0: the small configuration's, about 3.5 cm); depth noise and head-pose
  // error as ScanOptions' defaults. kOpen3d: a DeviceVariation drawn from the room's seed.
  double voxel_m = 0.0;
  // Headset errors taken out of the room's map (LeaveOutErrors' names: view-jitter,
  // surface-errors, depth-noise, patches, quantisation), to measure what each costs.
  std::vector<std::string> without;
};

// What stands where: every arm with its ground truth.
struct RoomArm {
  std::string model;               // the robot's name
  bool requested = true;           // an instance of the requested model (false: the distractor)
  Iso3 T_world_base = Iso3::Identity();
  JointValues joints;              // complete
  double pedestal_m = 0.0;         // 0: on the floor
  std::string placement;           // "wall", "table" or "open"
  // Where the headset's errors put this arm in the map (cell_simulator.h's mesh error: per-view
  // tracking error and, on the device's mesher, per-surface errors), for requested arms; unset
  // when too little of it was seen.
  std::optional<Iso3> T_world_base_mesh;
  double mesh_error_add_m = -1.0;  // the ADD of that motion; -1: not measured
};

struct SimulatedRoom {
  std::vector<Surface> surfaces;   // the headset's spatial map
  std::vector<RoomArm> arms;       // requested ones first
  Iso3 T_world_room = Iso3::Identity();  // room frame: floor at z = 0, centred on the floor
  Vec3 room_size_m = Vec3::Zero();
  double voxel_m = 0.0;
  std::vector<Prop> props;         // room frame
  std::vector<Vec3> head_path_world;
  Mesher mesher = Mesher::kOwn;
  DeviceVariation device;          // kOpen3d
  std::size_t triangles = 0;
};

// The requested model and, for RoomOptions::other_arm, another one.
struct RoomRobots {
  const RobotModel* requested = nullptr;
  const RobotModel* other = nullptr;
};

Result<SimulatedRoom> SimulateRoom(const RoomRobots& robots, const RoomOptions& options, std::uint64_t rng_seed);

}  // namespace arref::sim
