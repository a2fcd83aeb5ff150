// Builds the geometry of a simulated robot cell (robot, floor, walls, table, clutter) in the
// cell frame: z up, floor at z = 0, robot base at (0, 0, pedestal height).
#pragma once

#include <random>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/robot/robot_model.h"
#include "arref/sim/cell_simulator.h"
#include "arref/base/status.h"

namespace arref::sim {

struct CellScene {
  TriangleMesh mesh;            // everything, cell frame
  Iso3 T_cell_base = Iso3::Identity();
  JointValues joints;           // complete joint values of the main robot
  std::vector<Prop> props;
  Aabb footprint_cell;          // horizontal extent of the robot's base, cell frame
  std::size_t robot_vertices = 0;  // the robot's posed mesh: the first vertices of mesh
};

// A box with outward, counter-clockwise faces, rotated by yaw about z around its centre.
TriangleMesh MakeBox(const Vec3& center, const Vec3& size, double yaw = 0.0);

// Bounds of a box built by MakeBox (axis-aligned, so a yawed box gets its enclosing box).
Aabb BoxBounds(const Vec3& center, const Vec3& size, double yaw = 0.0);

// Footprint of a posed robot mesh (its own frame): the extent of what lies within 0.15 m of its
// lowest point (the base casting), up to that height.
Aabb FootprintOf(const TriangleMesh& posed);

// Horizontal gap between two boxes' footprints (0 when they overlap in x-y).
double HorizontalGap(const Aabb& a, const Aabb& b);

// Poses the robot and lays out the props. Random choices (clutter, second robot) use rng.
// Walls are placed beyond the walking path of scan.
Result<CellScene> BuildCellScene(const RobotModel& robot, const CellOptions& options, const ScanOptions& scan,
                                 std::mt19937_64& rng);

}  // namespace arref::sim
