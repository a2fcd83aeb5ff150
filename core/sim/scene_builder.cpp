#include "scene_builder.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <set>

#include "arref/robot/joint_motion.h"

namespace arref::sim {
namespace {

constexpr double kFloorSize = 8.0;
constexpr double kWallHeight = 2.6;
constexpr double kWallThickness = 0.1;
constexpr double kTableHeight = 0.75;
constexpr double kTableTop = 0.04;
constexpr double kTableLeg = 0.05;
const Vec3 kTableSize(1.2, 0.7, kTableHeight);
// The footprint is what stands on the floor: the base casting, not an arm that may hang out.
constexpr double kFootprintHeight = 0.15;

TriangleMesh MakeFloor(double size) {
  TriangleMesh m;
  const float h = static_cast<float>(size / 2);
  m.vertices = {{-h, -h, 0}, {h, -h, 0}, {-h, h, 0}, {h, h, 0}};
  m.triangles = {{0, 1, 2}, {1, 3, 2}};  // counter-clockwise from above: normal +z
  return m;
}

Aabb Translated(const Aabb& box, const Vec3& t) {
  Aabb out = box;
  out.min += t.cast<float>();
  out.max += t.cast<float>();
  return out;
}

Aabb Grown(const Aabb& box, double margin) {
  Aabb out = box;
  out.min.array() -= static_cast<float>(margin);
  out.max.array() += static_cast<float>(margin);
  return out;
}

bool OverlapXY(const Aabb& a, const Aabb& b) {
  return a.min.x() < b.max.x() && b.min.x() < a.max.x() && a.min.y() < b.max.y() && b.min.y() < a.max.y();
}

// Random joint values within limits, so the second robot looks like it is doing something.
Result<JointValues> RandomJoints(const RobotModel& robot, std::mt19937_64& rng) {
  JointValues values;
  for (const JointInfo& j : robot.ActuatedJoints()) {
    if (j.has_limits) {
      values[j.name] = std::uniform_real_distribution<double>(j.lower, j.upper)(rng);
    } else if (j.type != JointType::kPrismatic) {
      values[j.name] = std::uniform_real_distribution<double>(-std::numbers::pi, std::numbers::pi)(rng);
    }
  }
  return robot.CompleteJoints(values);
}

struct Layout {
  CellScene* scene;
  std::vector<Aabb> keep_out;  // clutter on the floor must not intersect these
  std::vector<Aabb> clutter;   // boxes placed so far
  Aabb room;                   // floor clutter stays inside (in front of the walls)
  Aabb base;                   // what the robot stands on: its footprint, or its pedestal
  std::mt19937_64* rng;
};

void AddProp(Layout& layout, const std::string& kind, const TriangleMesh& mesh, const Aabb& bounds) {
  layout.scene->mesh.Append(mesh);
  layout.scene->props.push_back({kind, bounds});
}

void AddBox(Layout& layout, const std::string& kind, const Vec3& center, const Vec3& size, double yaw = 0) {
  AddProp(layout, kind, MakeBox(center, size, yaw), BoxBounds(center, size, yaw));
}

void AddPedestal(Layout& layout, double height) {
  if (height <= 0) return;
  const Aabb& fp = layout.scene->footprint_cell;
  const Vec3 size(fp.max.x() - fp.min.x() + 0.2, fp.max.y() - fp.min.y() + 0.2, height);
  const Vec3 center(0.5 * (fp.min.x() + fp.max.x()), 0.5 * (fp.min.y() + fp.max.y()), height / 2);
  AddBox(layout, "pedestal", center, size);
  layout.keep_out.push_back(BoxBounds(center, size));
  layout.base = BoxBounds(center, size);
}

// Two walls meeting behind the robot (-x) and on its right (-y), beyond the walking path so
// the walker never looks at them from outside.
void AddWalls(Layout& layout, const CellOptions& cell, const ScanOptions& scan) {
  const double half_arc = std::min(scan.path_arc_deg, 359.0) / 2 * std::numbers::pi / 180;
  const double path_back = scan.path_radius_m * std::cos(half_arc);
  const double back = std::min({-1.0, static_cast<double>(layout.scene->footprint_cell.min.x()) - 0.5,
                                path_back - 0.4});
  double side = -std::max(2.4, scan.path_radius_m + 0.4);
  if (cell.second_robot) side = std::min(side, -(cell.second_robot_distance_m + 1.0));
  const double far = kFloorSize / 2;
  const Vec3 back_center(back - kWallThickness / 2, (side + far) / 2, kWallHeight / 2);
  const Vec3 back_size(kWallThickness, far - side, kWallHeight);
  const Vec3 side_center((back + far) / 2, side - kWallThickness / 2, kWallHeight / 2);
  const Vec3 side_size(far - back, kWallThickness, kWallHeight);
  AddBox(layout, "wall", back_center, back_size);
  AddBox(layout, "wall", side_center, side_size);
  layout.keep_out.push_back(BoxBounds(back_center, back_size));
  layout.room.min.x() = static_cast<float>(back);
  layout.room.min.y() = static_cast<float>(side);
  layout.keep_out.push_back(BoxBounds(side_center, side_size));
}

// Table on the robot's left (+y): its near edge table_gap_m from the base footprint (or the
// pedestal, which is what the table would bump into).
void AddTable(Layout& layout, double gap) {
  const Aabb& fp = layout.base;
  const double x0 = std::uniform_real_distribution<double>(-0.3, 0.3)(*layout.rng);
  const double y_near = fp.max.y() + gap;
  const Vec3 c(x0, y_near + kTableSize.y() / 2, kTableHeight);
  TriangleMesh table = MakeBox(c - Vec3(0, 0, kTableTop / 2), Vec3(kTableSize.x(), kTableSize.y(), kTableTop));
  const double leg_h = kTableHeight - kTableTop;
  for (int sx : {-1, 1})
    for (int sy : {-1, 1}) {
      const Vec3 leg(c.x() + sx * (kTableSize.x() / 2 - kTableLeg), c.y() + sy * (kTableSize.y() / 2 - kTableLeg),
                     leg_h / 2);
      table.Append(MakeBox(leg, Vec3(kTableLeg, kTableLeg, leg_h)));
    }
  const Aabb bounds = BoxBounds(Vec3(c.x(), c.y(), kTableHeight / 2), kTableSize);
  AddProp(layout, "table", table, bounds);
  layout.keep_out.push_back(bounds);
}

Status AddSecondRobot(Layout& layout, const RobotModel& robot, double distance) {
  auto& rng = *layout.rng;
  const double angle = std::uniform_real_distribution<double>(-2.1, -1.0)(rng);  // on the -y side
  const double yaw = std::uniform_real_distribution<double>(0, 2 * std::numbers::pi)(rng);
  // Random poses may put the arm through the floor: draw again, a real robot cannot be there.
  Result<TriangleMesh> posed = Status::Internal("no pose drawn");
  for (int attempt = 0; attempt < 50; ++attempt) {
    auto joints = RandomJoints(robot, rng);
    if (!joints.ok()) return joints.status().WithContext("second robot joints");
    posed = robot.PosedMesh(*joints);
    if (!posed.ok()) return posed.status().WithContext("posing the second robot");
    if (BoundsOf(posed->vertices).min.z() >= -0.005f) break;
  }
  const Iso3 T_cell_second = MakeYawPose(distance * std::cos(angle), distance * std::sin(angle), 0, yaw);
  TriangleMesh mesh;
  mesh.Append(*posed, T_cell_second);
  const Aabb bounds = BoundsOf(mesh.vertices);
  AddProp(layout, "second_robot", mesh, bounds);
  layout.keep_out.push_back(bounds);
  return Status::Ok();
}

bool FitsOnFloor(const Layout& layout, const Aabb& box) {
  if ((box.min.array() < layout.room.min.array()).any() || (box.max.array() > layout.room.max.array()).any())
    return false;
  for (const Aabb& k : layout.keep_out)
    if (OverlapXY(box, k)) return false;
  return true;
}

// A clutter box's centre and size: on the table top or on the floor around the robot.
struct BoxPlacement {
  Vec3 center, size;
  double yaw;
};

BoxPlacement DrawClutterBox(const Aabb* table, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> size_d(0.1, 0.5), unit(0, 1), angle_d(0, 2 * std::numbers::pi);
  BoxPlacement b{Vec3::Zero(), Vec3(size_d(rng), size_d(rng), size_d(rng)), angle_d(rng)};
  if (table != nullptr) {
    // Kept on the top whatever its yaw: its half diagonal stays inside the top.
    const double half = std::min(0.5 * b.size.head<2>().norm(), 0.5 * kTableSize.y() - 0.01);
    b.center = Vec3(table->min.x() + half + unit(rng) * (kTableSize.x() - 2 * half),
                    table->min.y() + half + unit(rng) * (kTableSize.y() - 2 * half), kTableHeight + b.size.z() / 2);
  } else {
    const double r = 0.5 + 1.3 * unit(rng), a = angle_d(rng);
    b.center = Vec3(r * std::cos(a), r * std::sin(a), b.size.z() / 2);
  }
  return b;
}

// Boxes of 0.1-0.5 m, about a third on the table, the rest on the floor around the robot,
// none intersecting the robot, the other props or each other.
void AddClutter(Layout& layout, int count, const Aabb* table) {
  auto& rng = *layout.rng;
  std::uniform_real_distribution<double> unit(0, 1);
  for (int i = 0; i < count; ++i) {
    const bool on_table = table != nullptr && unit(rng) < 0.35;
    bool placed = false;
    for (int attempt = 0; attempt < 100 && !placed; ++attempt) {
      const BoxPlacement b = DrawClutterBox(on_table ? table : nullptr, rng);
      const Aabb bounds = BoxBounds(b.center, b.size, b.yaw);
      // Table boxes overlap the table's own keep-out footprint by design: check only the others.
      const bool free = on_table ? std::none_of(layout.clutter.begin(), layout.clutter.end(),
                                                [&](const Aabb& c) { return OverlapXY(c, bounds); })
                                 : FitsOnFloor(layout, bounds);
      if (!free) continue;
      AddBox(layout, "clutter", b.center, b.size, b.yaw);
      layout.keep_out.push_back(bounds);
      layout.clutter.push_back(bounds);
      placed = true;
    }
    if (!placed) spdlog::debug("sim: no room for clutter box {} of {}", i + 1, count);
  }
}

}  // namespace

Aabb FootprintOf(const TriangleMesh& posed) {
  float min_z = std::numeric_limits<float>::max();
  for (const auto& v : posed.vertices) min_z = std::min(min_z, v.z());
  Aabb box;
  for (const auto& v : posed.vertices)
    if (v.z() <= min_z + kFootprintHeight) box.Extend(v);
  box.max.z() = min_z + static_cast<float>(kFootprintHeight);
  return box;
}


TriangleMesh MakeBox(const Vec3& center, const Vec3& size, double yaw) {
  TriangleMesh m;
  const Iso3 T = MakeYawPose(center.x(), center.y(), center.z(), yaw);
  for (int i = 0; i < 8; ++i) {
    const Vec3 corner((i & 1 ? 0.5 : -0.5) * size.x(), (i & 2 ? 0.5 : -0.5) * size.y(),
                      (i & 4 ? 0.5 : -0.5) * size.z());
    m.vertices.push_back((T * corner).cast<float>());
  }
  // Corner i has bits (x, y, z); each face is wound counter-clockwise seen from outside.
  m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  return m;
}

Aabb BoxBounds(const Vec3& center, const Vec3& size, double yaw) {
  return BoundsOf(MakeBox(center, size, yaw).vertices);
}

double HorizontalGap(const Aabb& a, const Aabb& b) {
  const double dx = std::max({0.0f, a.min.x() - b.max.x(), b.min.x() - a.max.x()});
  const double dy = std::max({0.0f, a.min.y() - b.max.y(), b.min.y() - a.max.y()});
  return std::hypot(dx, dy);
}

Result<CellScene> BuildCellScene(const RobotModel& robot, const CellOptions& options, const ScanOptions& scan,
                                 std::mt19937_64& rng) {
  CellScene scene;
  auto joints = robot.CompleteJoints(options.joints);
  if (!joints.ok()) return joints.status().WithContext("cell.joints");
  scene.joints = *joints;
  auto posed = robot.PosedMesh(scene.joints);
  if (!posed.ok()) return posed.status().WithContext("posing the robot");
  if (posed->empty()) return Status::FailedPrecondition("robot '" + robot.name() + "' has no geometry to simulate");

  scene.T_cell_base = MakeYawPose(0, 0, options.pedestal_height_m, options.base_yaw_deg * std::numbers::pi / 180);
  // What stands on the floor or pedestal: the fixed links (the arm may reach below them).
  ARREF_ASSIGN_OR_RETURN(const std::set<std::string> fixed, FixedLinks(robot));
  TriangleMesh standing;
  if (!fixed.empty()) {
    ARREF_ASSIGN_OR_RETURN(standing, robot.PosedMesh(scene.joints, fixed));
  }
  TriangleMesh headed;  // turned to the robot's heading, for its footprint in the cell
  headed.Append(standing.empty() ? *posed : standing, Iso3(scene.T_cell_base.linear()));
  scene.footprint_cell = Translated(FootprintOf(headed), scene.T_cell_base.translation());
  // Without the robot the footprint stays reserved, so the rest of the cell is laid out alike.
  if (options.robot_present) {
    scene.mesh.Append(*posed, scene.T_cell_base);
    scene.robot_vertices = posed->vertices.size();
  }
  scene.props.push_back({"robot_footprint", scene.footprint_cell});

  Layout layout{&scene, {Grown(scene.footprint_cell, 0.05)}, {}, BoundsOf(MakeFloor(kFloorSize).vertices),
                scene.footprint_cell, &rng};
  layout.room.max.z() = std::numeric_limits<float>::max();
  AddPedestal(layout, options.pedestal_height_m);
  AddProp(layout, "floor", MakeFloor(kFloorSize), BoundsOf(MakeFloor(kFloorSize).vertices));
  if (options.walls) AddWalls(layout, options, scan);
  if (options.table) AddTable(layout, options.table_gap_m);
  if (options.second_robot) ARREF_RETURN_IF_ERROR(AddSecondRobot(layout, robot, options.second_robot_distance_m));
  const Aabb* table = nullptr;
  for (const Prop& p : scene.props)
    if (p.kind == "table") table = &p.bounds_cell;
  // Copy: AddClutter appends props, which may move the table's entry.
  const Aabb table_bounds = table ? *table : Aabb{};
  AddClutter(layout, options.clutter_boxes, table ? &table_bounds : nullptr);
  spdlog::debug("sim: cell scene has {} triangles, {} props", scene.mesh.triangles.size(), scene.props.size());
  return scene;
}

}  // namespace arref::sim
