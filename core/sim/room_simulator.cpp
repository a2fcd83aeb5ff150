#include "arref/sim/room_simulator.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "arref/fusion/raycaster.h"
#include "arref/fusion/tsdf.h"
#include "arref/scene/sampling.h"
#include "mesh_imprint.h"
#include "open3d_mesher.h"
#include "scan_common.h"
#include "scene_builder.h"

namespace arref::sim {
namespace {

using detail::Stream;
using U = std::uniform_real_distribution<double>;
constexpr double kWall = 0.1;
using detail::kNoiseSigmasInBand;
using detail::kSecondsPerView;
using detail::MeshImprint;
constexpr double kSmallVoxel = 0.0346;  // the small configuration's (1,000 triangles per m^3)

// One placed object's footprint (room frame, x-y) and what it is.
struct Placed {
  Aabb box;
  bool tall = false;  // the walker cannot stand in it (shelves, arms, cabinets)
};

struct Layout {
  Vec3 size;                 // room x, y, height
  TriangleMesh mesh;         // room frame
  std::vector<Prop> props;
  std::vector<Placed> placed;
  std::vector<Aabb> table_tops;  // for clutter on tables
  std::mt19937_64* rng;
};

bool OverlapXY(const Aabb& a, const Aabb& b) {
  return a.min.x() < b.max.x() && b.min.x() < a.max.x() && a.min.y() < b.max.y() && b.min.y() < a.max.y();
}

bool InsideFloor(const Layout& l, const Aabb& b, double margin) {
  const double hx = l.size.x() / 2 - margin, hy = l.size.y() / 2 - margin;
  return b.min.x() >= -hx && b.max.x() <= hx && b.min.y() >= -hy && b.max.y() <= hy;
}

bool ClearOfOthers(const Layout& l, const Aabb& b) {
  return std::none_of(l.placed.begin(), l.placed.end(), [&](const Placed& p) { return OverlapXY(p.box, b); });
}

bool Free(const Layout& l, const Aabb& b) { return InsideFloor(l, b, 0.0) && ClearOfOthers(l, b); }

void AddBox(Layout& l, const std::string& kind, const Vec3& c, const Vec3& s, double yaw = 0) {
  l.mesh.Append(MakeBox(c, s, yaw));
  l.props.push_back({kind, BoxBounds(c, s, yaw)});
}

void AddShell(Layout& l) {
  const double hx = l.size.x() / 2, hy = l.size.y() / 2, h = l.size.z();
  AddBox(l, "floor", Vec3(0, 0, -0.05), Vec3(l.size.x() + 2 * kWall, l.size.y() + 2 * kWall, 0.1));
  AddBox(l, "ceiling", Vec3(0, 0, h + 0.05), Vec3(l.size.x() + 2 * kWall, l.size.y() + 2 * kWall, 0.1));
  AddBox(l, "wall", Vec3(-hx - kWall / 2, 0, h / 2), Vec3(kWall, l.size.y(), h));
  AddBox(l, "wall", Vec3(hx + kWall / 2, 0, h / 2), Vec3(kWall, l.size.y(), h));
  AddBox(l, "wall", Vec3(0, -hy - kWall / 2, h / 2), Vec3(l.size.x(), kWall, h));
  AddBox(l, "wall", Vec3(0, hy + kWall / 2, h / 2), Vec3(l.size.x(), kWall, h));
}

// A table of its own size, axis-aligned, at `centre` (x-y): top and four legs.
Aabb AddTable(Layout& l, const Vec3& centre, const Vec3& size) {
  const double top = 0.04, leg = 0.05;
  TriangleMesh t = MakeBox(Vec3(centre.x(), centre.y(), size.z() - top / 2), Vec3(size.x(), size.y(), top));
  for (int sx : {-1, 1})
    for (int sy : {-1, 1})
      t.Append(MakeBox(Vec3(centre.x() + sx * (size.x() / 2 - leg), centre.y() + sy * (size.y() / 2 - leg), (size.z() - top) / 2),
                       Vec3(leg, leg, size.z() - top)));
  const Aabb bounds = BoxBounds(Vec3(centre.x(), centre.y(), size.z() / 2), size);
  l.mesh.Append(t);
  l.props.push_back({"table", bounds});
  l.placed.push_back({bounds, false});
  l.table_tops.push_back(bounds);
  return bounds;
}

Vec3 DrawTableSize(std::mt19937_64& rng) { return Vec3(U(0.8, 1.6)(rng), U(0.6, 0.9)(rng), U(0.70, 0.80)(rng)); }

// A shelf against a wall: two sides, a back, boards; its open side faces the room.
void AddShelf(Layout& l) {
  auto& rng = *l.rng;
  for (int attempt = 0; attempt < 50; ++attempt) {
    const double width = U(0.8, 2.0)(rng), depth = U(0.3, 0.5)(rng), height = U(1.2, 2.2)(rng);
    const int wall = std::uniform_int_distribution<int>(0, 3)(rng);
    const bool along_x = wall >= 2;  // walls 2, 3 are at -y, +y
    const double sx = along_x ? width : depth, sy = along_x ? depth : width;
    const double hx = l.size.x() / 2, hy = l.size.y() / 2;
    Vec3 c;
    if (along_x) c = Vec3(U(-hx + sx / 2, hx - sx / 2)(rng), (wall == 2 ? -1 : 1) * (hy - sy / 2), height / 2);
    else c = Vec3((wall == 0 ? -1 : 1) * (hx - sx / 2), U(-hy + sy / 2, hy - sy / 2)(rng), height / 2);
    const Aabb bounds = BoxBounds(c, Vec3(sx, sy, height));
    if (!Free(l, bounds.Grown(0.05f))) continue;
    const double t = 0.02;
    const Vec3 out = along_x ? Vec3(0, wall == 2 ? 1 : -1, 0) : Vec3(wall == 0 ? 1 : -1, 0, 0);  // into the room
    const Vec3 side_axis = along_x ? Vec3::UnitX() : Vec3::UnitY();
    const Vec3 panel_size = along_x ? Vec3(t, sy, height) : Vec3(sx, t, height);
    for (int s : {-1, 1}) AddBox(l, "shelf", c + s * (width / 2 - t / 2) * side_axis, panel_size);
    AddBox(l, "shelf", c - out * (depth / 2 - t / 2), along_x ? Vec3(sx, t, height) : Vec3(t, sy, height));
    const int boards = std::uniform_int_distribution<int>(3, 5)(rng);
    for (int b = 0; b < boards; ++b) {
      const double z = height * (b + 0.5) / boards;
      AddBox(l, "shelf", Vec3(c.x(), c.y(), z), Vec3(sx, sy, t));
      if (U(0, 1)(rng) < 0.6) {  // something on the board
        const Vec3 s(U(0.1, 0.3)(rng), U(0.1, 0.3)(rng), std::min(U(0.1, 0.3)(rng), height / boards - 0.05));
        const double along = U(-width / 2 + 0.2, width / 2 - 0.2)(rng);
        AddBox(l, "clutter", Vec3(c.x(), c.y(), z + t / 2 + s.z() / 2) + along * side_axis, s);
      }
    }
    l.placed.push_back({bounds, true});
    return;
  }
}

void AddClutter(Layout& l, int count) {
  auto& rng = *l.rng;
  for (int i = 0; i < count; ++i) {
    for (int attempt = 0; attempt < 50; ++attempt) {
      const Vec3 s(U(0.1, 0.6)(rng), U(0.1, 0.6)(rng), U(0.1, 0.8)(rng));
      const double yaw = U(0, 2 * std::numbers::pi)(rng);
      const bool on_table = !l.table_tops.empty() && U(0, 1)(rng) < 0.3;
      Vec3 c;
      if (on_table) {
        const Aabb& top = l.table_tops[std::uniform_int_distribution<std::size_t>(0, l.table_tops.size() - 1)(rng)];
        const double half = 0.5 * s.head<2>().norm();
        if (top.max.x() - top.min.x() < 2 * half || top.max.y() - top.min.y() < 2 * half) continue;
        c = Vec3(U(top.min.x() + half, top.max.x() - half)(rng), U(top.min.y() + half, top.max.y() - half)(rng),
                 top.max.z() + std::min(s.z(), 0.4) / 2);
        AddBox(l, "clutter", c, Vec3(s.x(), s.y(), std::min(s.z(), 0.4)), yaw);
        break;
      }
      c = Vec3(U(-l.size.x() / 2, l.size.x() / 2)(rng), U(-l.size.y() / 2, l.size.y() / 2)(rng), s.z() / 2);
      const Aabb b = BoxBounds(c, s, yaw);
      if (!Free(l, b)) continue;
      AddBox(l, "clutter", c, s, yaw);
      l.placed.push_back({b, false});
      break;
    }
  }
}

// Random joints within +-0.5 rad of zero (as the bench's cells), the arm above its mounting.
Result<JointValues> DrawJoints(const RobotModel& robot, std::mt19937_64& rng) {
  for (int attempt = 0; attempt < 30; ++attempt) {
    JointValues joints;
    for (const auto& j : robot.ActuatedJoints()) {
      double v = U(-0.5, 0.5)(rng);
      if (j.has_limits) v = std::clamp(v, j.lower, j.upper);
      joints[j.name] = v;
    }
    ARREF_ASSIGN_OR_RETURN(JointValues complete, robot.CompleteJoints(joints));
    ARREF_ASSIGN_OR_RETURN(const TriangleMesh posed, robot.PosedMesh(complete));
    if (BoundsOf(posed.vertices).min.z() >= -0.01f) return complete;
  }
  return robot.CompleteJoints({});
}

struct ArmPlan {
  const RobotModel* robot;
  bool requested;
  const JointValues* joints = nullptr;  // given: this pose (else drawn)
};

// Places one arm (and its pedestal, and for "table" a table beside it); false when no place was found.
Result<bool> PlaceArm(Layout& l, const ArmPlan& plan, RoomArm* arm, TriangleMesh* arm_mesh_room, Iso3* T_room_base) {
  auto& rng = *l.rng;
  if (plan.joints) {
    arm->joints = *plan.joints;
  } else {
    ARREF_ASSIGN_OR_RETURN(arm->joints, DrawJoints(*plan.robot, rng));
  }
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh posed, plan.robot->PosedMesh(arm->joints));
  if (posed.empty()) return Status::FailedPrecondition("robot '" + plan.robot->name() + "' has no geometry to simulate");
  arm->model = plan.robot->name();
  arm->requested = plan.requested;
  arm->pedestal_m = U(0, 1)(rng) < 0.4 ? U(0.2, 0.7)(rng) : 0.0;
  const double u = U(0, 1)(rng);
  arm->placement = u < 0.4 ? "wall" : u < 0.75 ? "table" : "open";
  for (int attempt = 0; attempt < 200; ++attempt) {
    const double yaw = U(0, 2 * std::numbers::pi)(rng);
    TriangleMesh headed;
    headed.Append(posed, MakeYawPose(0, 0, 0, yaw));
    const Aabb reach = BoundsOf(headed.vertices);
    const Aabb foot = FootprintOf(headed);
    const double hx = l.size.x() / 2, hy = l.size.y() / 2;
    Vec3 p(U(-hx, hx)(rng), U(-hy, hy)(rng), arm->pedestal_m);
    if (arm->placement == "wall") {  // its base 0.1-0.6 m from a wall
      const int wall = std::uniform_int_distribution<int>(0, 3)(rng);
      const double gap = U(0.1, 0.6)(rng) + 0.1;
      if (wall == 0) p.x() = -hx + gap - foot.min.x();
      if (wall == 1) p.x() = hx - gap - foot.max.x();
      if (wall == 2) p.y() = -hy + gap - foot.min.y();
      if (wall == 3) p.y() = hy - gap - foot.max.y();
    }
    Aabb arm_box = reach;
    arm_box.min += p.cast<float>(), arm_box.max += p.cast<float>();
    Aabb foot_room = foot;
    foot_room.min += p.cast<float>(), foot_room.max += p.cast<float>();
    Aabb pedestal = foot_room.Grown(0.1f);
    pedestal.min.z() = 0, pedestal.max.z() = static_cast<float>(arm->pedestal_m);
    if (!InsideFloor(l, arm_box, 0.05) || !ClearOfOthers(l, arm_box.Grown(0.25f)) || !Free(l, pedestal.Grown(0.05f))) continue;
    std::vector<Placed> added = {{arm_box.Grown(0.1f), true}};
    if (arm->placement == "table") {
      const Vec3 ts = DrawTableSize(rng);
      const double gap = U(0.05, 0.4)(rng);
      const int side = std::uniform_int_distribution<int>(0, 3)(rng);
      const Aabb& near = arm->pedestal_m > 0 ? pedestal : foot_room;
      Vec3 c(U(near.min.x(), near.max.x())(rng), U(near.min.y(), near.max.y())(rng), 0);
      if (side == 0) c.x() = near.max.x() + gap + ts.x() / 2;
      if (side == 1) c.x() = near.min.x() - gap - ts.x() / 2;
      if (side == 2) c.y() = near.max.y() + gap + ts.y() / 2;
      if (side == 3) c.y() = near.min.y() - gap - ts.y() / 2;
      const Aabb table = BoxBounds(Vec3(c.x(), c.y(), ts.z() / 2), ts);
      // The arm may reach over the table, never through it.
      bool hits = !Free(l, table);
      for (const Vec3f& v : headed.vertices) {
        const Vec3f w = v + p.cast<float>();
        hits = hits || (w.z() < table.max.z() + 0.03f && w.x() > table.min.x() && w.x() < table.max.x() &&
                        w.y() > table.min.y() && w.y() < table.max.y());
      }
      if (hits) continue;
      l.placed.insert(l.placed.end(), added.begin(), added.end());
      AddTable(l, c, ts);
    } else {
      l.placed.insert(l.placed.end(), added.begin(), added.end());
    }
    if (arm->pedestal_m > 0) {
      const Vec3 size = (pedestal.max - pedestal.min).cast<double>();
      AddBox(l, "pedestal", (pedestal.min.cast<double>() + pedestal.max.cast<double>()) / 2, size);
    }
    *T_room_base = MakeYawPose(p.x(), p.y(), p.z(), yaw);
    arm_mesh_room->Append(posed, *T_room_base);
    l.mesh.Append(posed, *T_room_base);
    l.props.push_back({plan.requested ? "robot" : "other_robot", arm_box});
    return true;
  }
  return false;
}

struct View {
  Iso3 T_room_camera_true, T_room_camera_believed;
};

bool EyeFree(const Layout& l, const Vec3& eye) {
  if (std::abs(eye.x()) > l.size.x() / 2 - 0.3 || std::abs(eye.y()) > l.size.y() / 2 - 0.3) return false;
  Aabb point;
  point.Extend(eye.cast<float>());
  return std::none_of(l.placed.begin(), l.placed.end(), [&](const Placed& p) { return p.tall && OverlapXY(p.box.Grown(0.2f), point); });
}

// The walker circles every arm on an arc of their own (as in a cell) and looks round the room.
std::vector<View> Walk(const Layout& l, const std::vector<std::pair<Iso3, double>>& arms, const ScanOptions& scan,
                       double arc_deg, double distance_m, std::mt19937_64& rng) {
  std::vector<View> views;
  auto add = [&](const Vec3& eye, const Vec3& target) {
    const Iso3 believed = LookAt(eye, target);
    views.push_back({believed * detail::RandomJitter(scan, rng), believed});
  };
  constexpr int kArmViews = 16, kRoomViews = 16;
  for (const auto& [T_room_base, reach] : arms) {
    const double centre = U(0, 2 * std::numbers::pi)(rng), arc = arc_deg * std::numbers::pi / 180;
    const double radius = std::max(distance_m, reach + 0.5);
    for (int i = 0; i < kArmViews; ++i) {
      const double a = centre - arc / 2 + arc * i / (kArmViews - 1);
      const Vec3 eye = T_room_base.translation() + Vec3(radius * std::cos(a), radius * std::sin(a), 0);
      const Vec3 e(eye.x(), eye.y(), U(1.5, 1.8)(rng));
      if (!EyeFree(l, e)) continue;
      add(e, T_room_base * Vec3(0, 0, U(0.3, 0.8)(rng)));
    }
  }
  for (int i = 0; i < kRoomViews * 4 && views.size() < arms.size() * kArmViews + kRoomViews; ++i) {
    const Vec3 eye(U(-l.size.x() / 2, l.size.x() / 2)(rng), U(-l.size.y() / 2, l.size.y() / 2)(rng), U(1.5, 1.8)(rng));
    if (!EyeFree(l, eye)) continue;
    const double a = U(0, 2 * std::numbers::pi)(rng);
    add(eye, eye + Vec3(2.5 * std::cos(a), 2.5 * std::sin(a), U(-1.6, -0.4)(rng)));
  }
  return views;
}

// Depth that never returns (dark or shiny spots): half on the arms, half anywhere.
std::vector<std::pair<Vec3, double>> Patches(const TriangleMesh& arms_room, const TriangleMesh& room, const DeviceVariation& d,
                                             std::uint64_t seed) {
  std::vector<std::pair<Vec3, double>> patches;
  auto rng = Stream(seed, 21);
  const PointCloud on_arms = arms_room.empty() ? PointCloud{} : SampleSurface(arms_room, 256, rng());
  const PointCloud anywhere = SampleSurface(room, 1024, rng());
  for (int i = 0; i < d.missing_patches * 2; ++i) {  // a room has more such spots than a cell
    const bool arm = !on_arms.empty() && U(0, 1)(rng) < 0.25;
    const PointCloud& from = arm ? on_arms : anywhere;
    if (from.empty()) continue;
    const Vec3 c = from.points[std::uniform_int_distribution<std::size_t>(0, from.size() - 1)(rng)].cast<double>();
    patches.push_back({c, d.patch_radius_max_m * U(0.25, 1.0)(rng)});
  }
  return patches;
}

void DropPatches(RangeImage& range, const PinholeCamera& camera, const Iso3& T_room_camera,
                 const std::vector<std::pair<Vec3, double>>& patches) {
  if (patches.empty()) return;
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      float& r = range[static_cast<std::size_t>(v) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(u)];
      if (r <= 0) continue;
      const Vec3 hit = T_room_camera * (camera.RayDirection(u, v) * static_cast<double>(r));
      for (const auto& [c, radius] : patches)
        if ((hit - c).squaredNorm() < radius * radius) {
          r = 0.0f;
          break;
        }
    }
}

// Every view's depth image fed to each arm's imprint, as it is fused.
void Imprint(const PinholeCamera& camera, const Iso3& T_world_room, const View& view, const RangeImage& range,
             const ScanOptions& scan, std::vector<MeshImprint>& imprints) {
  for (MeshImprint& m : imprints)
    m.AddView(camera, T_world_room * view.T_room_camera_true, T_world_room * view.T_room_camera_believed, range,
              detail::SeenTolerance(scan));
}

Result<std::vector<Surface>> FuseOwn(const Layout& l, const std::vector<View>& views, const ScanOptions& scan, double voxel,
                                     const Iso3& T_world_room, std::uint64_t seed, std::vector<MeshImprint>& imprints) {
  ARREF_ASSIGN_OR_RETURN(const RayCaster caster, RayCaster::Create(l.mesh));
  const PinholeCamera camera = PinholeCamera::FromFov(scan.image_width, scan.image_height, scan.fov_horizontal_deg);
  TsdfOptions tsdf;
  tsdf.voxel_m = voxel;
  tsdf.truncation_m = std::max(3 * voxel, kNoiseSigmasInBand * scan.depth_noise_m);
  tsdf.crop_center = T_world_room * Vec3(0, 0, l.size.z() / 2);
  tsdf.crop_radius_m = l.size.norm() / 2 + 0.5;
  TsdfVolume volume(tsdf);
  for (int i = 0; i < static_cast<int>(views.size()); ++i) {
    std::vector<float> incidence;
    RangeImage range = caster.Render(camera, views[static_cast<std::size_t>(i)].T_room_camera_true, scan.max_range_m, &incidence);
    detail::AddRangeNoise(range, scan, seed, i);
    Imprint(camera, T_world_room, views[static_cast<std::size_t>(i)], range, scan, imprints);
    ARREF_RETURN_IF_ERROR(volume.Integrate(camera, T_world_room * views[static_cast<std::size_t>(i)].T_room_camera_believed,
                                           range, incidence));
  }
  return SplitIntoSurfaces(volume.ExtractMesh(), 1.0, static_cast<double>(views.size()) * kSecondsPerView);
}

Result<std::vector<Surface>> FuseOpen3d(const Layout& l, const TriangleMesh& arms_room, const std::vector<View>& views,
                                        const ScanOptions& scan, const DeviceVariation& device, const Iso3& T_world_room,
                                        std::uint64_t seed, std::vector<MeshImprint>& imprints) {
  ARREF_ASSIGN_OR_RETURN(const RayCaster caster, RayCaster::Create(l.mesh));
  const PinholeCamera camera = PinholeCamera::FromFov(scan.image_width, scan.image_height, scan.fov_horizontal_deg);
  const auto patches = Patches(arms_room, l.mesh, device, seed);
  std::vector<RangeImage> ranges;
  std::vector<Iso3> T_world_camera;
  for (int i = 0; i < static_cast<int>(views.size()); ++i) {
    const View& v = views[static_cast<std::size_t>(i)];
    RangeImage range = caster.Render(camera, v.T_room_camera_true, scan.max_range_m);
    detail::AddRangeNoise(range, scan, seed, i);
    DropPatches(range, camera, v.T_room_camera_true, patches);
    Imprint(camera, T_world_room, v, range, scan, imprints);
    ranges.push_back(std::move(range));
    T_world_camera.push_back(T_world_room * v.T_room_camera_believed);
  }
  return detail::MeshLikeTheDevice(camera, T_world_camera, ranges, device, scan.max_range_m, seed);
}

Status Validate(const RoomRobots& robots, const RoomOptions& o) {
  if (!robots.requested) return Status::InvalidArgument("room: no requested robot model");
  if (o.arms < 0 || o.arms > 2) return Status::InvalidArgument(fmt::format("room.arms = {}: must be 0, 1 or 2", o.arms));
  if (o.other_arm && !robots.other) return Status::InvalidArgument("room.other_arm: no other robot model given");
  if (!(o.min_side_m >= 2.0 && o.max_side_m >= o.min_side_m && o.max_side_m <= 20.0))
    return Status::InvalidArgument(fmt::format("room sides {}-{} m: must lie in [2, 20] m, min <= max", o.min_side_m, o.max_side_m));
  if (!(o.min_height_m >= 2.0 && o.max_height_m >= o.min_height_m && o.max_height_m <= 5.0))
    return Status::InvalidArgument(fmt::format("room heights {}-{} m: must lie in [2, 5] m, min <= max", o.min_height_m, o.max_height_m));
  if (!(o.voxel_m == 0 || (o.voxel_m >= 0.01 && o.voxel_m <= 0.1)))
    return Status::InvalidArgument(fmt::format("room.voxel_m = {}: must be 0 or in [0.01, 0.1]", o.voxel_m));
  if (!MesherAvailable(o.mesher))
    return Status::FailedPrecondition("room mesher open3d: arref was built without Open3D (apt-get install libopen3d-dev)");
  return Status::Ok();
}

}  // namespace

Result<SimulatedRoom> SimulateRoom(const RoomRobots& robots, const RoomOptions& options, std::uint64_t rng_seed) {
  ARREF_RETURN_IF_ERROR(Validate(robots, options));
  std::mt19937_64 rng(rng_seed);
  SimulatedRoom room;
  room.mesher = options.mesher;
  // The headset's errors a diagnostic takes out (LeaveOutErrors), into the scan and the device.
  SimOptions errors;
  errors.fusion.mesher = options.mesher;
  errors.fusion.device = DrawDeviceVariation(rng_seed);
  ARREF_RETURN_IF_ERROR(LeaveOutErrors(options.without, rng_seed, &errors));
  room.device = *errors.fusion.device;
  room.room_size_m = Vec3(U(options.min_side_m, options.max_side_m)(rng), U(options.min_side_m, options.max_side_m)(rng),
                          U(options.min_height_m, options.max_height_m)(rng));
  room.T_world_room = MakeYawPose(U(-3, 3)(rng), U(-3, 3)(rng), U(-1.6, -1.2)(rng), U(0, 2 * std::numbers::pi)(rng));
  Layout l{room.room_size_m, {}, {}, {}, {}, &rng};
  AddShell(l);
  // The requested model's arms share one pose (one program runs on both, and a request carries
  // one joint state), unless options.same_joints is off.
  std::optional<JointValues> shared;
  if (options.arms > 0 && options.same_joints) {
    ARREF_ASSIGN_OR_RETURN(shared, DrawJoints(*robots.requested, rng));
  }
  std::vector<ArmPlan> plans(static_cast<std::size_t>(options.arms), ArmPlan{robots.requested, true, shared ? &*shared : nullptr});
  if (options.other_arm) plans.push_back({robots.other, false});
  TriangleMesh arms_room;
  std::vector<std::pair<Iso3, double>> walked;  // each arm's base and horizontal reach
  for (const ArmPlan& plan : plans) {
    RoomArm arm;
    Iso3 T_room_base;
    ARREF_ASSIGN_OR_RETURN(const bool placed, PlaceArm(l, plan, &arm, &arms_room, &T_room_base));
    if (!placed) return Status::FailedPrecondition(fmt::format("room {}: no place for arm '{}' in a {:.1f} x {:.1f} m room",
                                                               rng_seed, plan.robot->name(), l.size.x(), l.size.y()));
    arm.T_world_base = room.T_world_room * T_room_base;
    ARREF_ASSIGN_OR_RETURN(const TriangleMesh posed, plan.robot->PosedMesh(arm.joints));
    double reach = 0;
    for (const Vec3f& v : posed.vertices) reach = std::max(reach, static_cast<double>(v.head<2>().norm()));
    walked.push_back({T_room_base, reach});
    room.arms.push_back(std::move(arm));
  }
  const int area_m2 = static_cast<int>(l.size.x() * l.size.y());
  for (int i = 0, n = std::uniform_int_distribution<int>(0, 1 + area_m2 / 30)(rng); i < n; ++i)
    for (int attempt = 0; attempt < 50; ++attempt) {
      const Vec3 ts = DrawTableSize(rng);
      const Vec3 c(U(-l.size.x() / 2, l.size.x() / 2)(rng), U(-l.size.y() / 2, l.size.y() / 2)(rng), 0);
      if (!Free(l, BoxBounds(Vec3(c.x(), c.y(), ts.z() / 2), ts).Grown(0.2f))) continue;
      AddTable(l, c, ts);
      break;
    }
  for (int i = 0, n = std::uniform_int_distribution<int>(0, 3)(rng); i < n; ++i) AddShelf(l);
  AddClutter(l, std::uniform_int_distribution<int>(3, 6 + area_m2 / 8)(rng));
  room.props = l.props;

  ScanOptions scan = errors.scan;
  double arc = U(120, 300)(rng), distance = U(1.2, 2.2)(rng);
  if (options.mesher == Mesher::kOpen3d) {
    scan.depth_noise_m = room.device.depth_noise_m;
    arc = room.device.walk_arc_deg, distance = std::min(room.device.walk_distance_m, 2.5);
  }
  const std::vector<View> views = Walk(l, walked, scan, arc, distance, rng);
  std::vector<MeshImprint> imprints;
  std::vector<std::size_t> imprinted;  // the arm of each imprint
  for (std::size_t a = 0; a < room.arms.size(); ++a) {
    const RoomArm& arm = room.arms[a];
    if (!arm.requested) continue;
    ARREF_ASSIGN_OR_RETURN(const TriangleMesh posed, robots.requested->PosedMesh(arm.joints));
    PointCloud points = SampleSurface(posed, 2000, rng_seed + a);
    points.Transform(arm.T_world_base);
    imprints.emplace_back(std::move(points), arm.T_world_base.translation());
    imprinted.push_back(a);
  }
  for (const View& v : views) room.head_path_world.push_back(room.T_world_room * v.T_room_camera_believed.translation());
  if (options.mesher == Mesher::kOpen3d) {
    room.voxel_m = room.device.voxel_m;
    ARREF_ASSIGN_OR_RETURN(room.surfaces, FuseOpen3d(l, arms_room, views, scan, room.device, room.T_world_room, rng_seed, imprints));
  } else {
    room.voxel_m = options.voxel_m > 0 ? options.voxel_m : kSmallVoxel;
    ARREF_ASSIGN_OR_RETURN(room.surfaces, FuseOwn(l, views, scan, room.voxel_m, room.T_world_room, rng_seed, imprints));
  }
  const auto surface_errors = options.mesher == Mesher::kOpen3d ? detail::SurfaceErrors(room.device, rng_seed)
                                                                : std::function<Iso3(const Vec3&)>{};
  for (std::size_t k = 0; k < imprints.size(); ++k) {
    const std::optional<Iso3> T_mesh_true = imprints[k].Motion(surface_errors);
    if (!T_mesh_true) continue;  // too little of the arm seen: not measured
    RoomArm& arm = room.arms[imprinted[k]];
    arm.mesh_error_add_m = imprints[k].AddOf(*T_mesh_true);
    arm.T_world_base_mesh = *T_mesh_true * arm.T_world_base;
  }
  for (const Surface& s : room.surfaces) room.triangles += s.mesh.triangles.size();
  if (room.triangles == 0) return Status::FailedPrecondition(fmt::format("room {}: the simulated walk mapped nothing", rng_seed));
  spdlog::debug("sim: room {}: {:.1f} x {:.1f} x {:.1f} m, {} arms, {} views, {} triangles ({} mesher)", rng_seed, l.size.x(),
                l.size.y(), l.size.z(), room.arms.size(), views.size(), room.triangles, MesherName(options.mesher));
  return room;
}

}  // namespace arref::sim
