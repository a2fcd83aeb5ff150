#include "arref/sim/cell_simulator.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <tuple>

#include "arref/fusion/raycaster.h"
#include "arref/scene/sampling.h"
#include "arref/scene/spatial_mesh.h"
#include "mesh_imprint.h"
#include "open3d_mesher.h"
#include "scan_common.h"
#include "scene_builder.h"
#include "arref/fusion/tsdf.h"

namespace arref::sim {
namespace {

using detail::kNoiseSigmasInBand;
using detail::kSecondsPerView;

// Surface area per cubic metre of a mapped cell (floor, walls, robot, furniture in the 2 m
// sphere). Surface nets emits ~2 triangles per voxel face of surface, so a density of
// triangles_per_m3 needs voxels of sqrt(2 * kSurfacePerVolume / triangles_per_m3).
constexpr double kSurfacePerVolume = 0.6;
constexpr double kMinVoxel = 0.01;  // finer gains nothing at 8 mm depth noise and costs memory
constexpr double kMaxVoxel = 0.05;

using Clock = std::chrono::steady_clock;
double SecondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

Status Invalid(const std::string& field, double value, const std::string& rule) {
  std::ostringstream message;
  message << field << " = " << value << ": " << rule;
  return Status::InvalidArgument(message.str());
}

// Each check: field name, value, whether it is acceptable, what it must be.
Status CheckAll(std::initializer_list<std::tuple<const char*, double, bool, const char*>> checks) {
  for (const auto& [field, value, ok, rule] : checks)
    if (!std::isfinite(value) || !ok) return Invalid(field, value, rule);
  return Status::Ok();
}

Status ValidateCell(const CellOptions& c) {
  return CheckAll({
      {"cell.pedestal_height_m", c.pedestal_height_m, c.pedestal_height_m >= 0, "must be >= 0"},
      {"cell.base_yaw_deg", c.base_yaw_deg, std::isfinite(c.base_yaw_deg), "must be finite"},
      {"cell.table_gap_m", c.table_gap_m, c.table_gap_m >= 0, "must be >= 0"},
      {"cell.clutter_boxes", c.clutter_boxes, c.clutter_boxes >= 0 && c.clutter_boxes <= 1000, "must be in [0, 1000]"},
      {"cell.second_robot_distance_m", c.second_robot_distance_m,
       !c.second_robot || (c.second_robot_distance_m > 0 && c.second_robot_distance_m <= 3.5),
       "must be in (0, 3.5] (the floor is 8 m wide)"},
      {"cell.motion.amplitude_rad", c.motion.amplitude_rad, c.motion.amplitude_rad >= 0, "must be >= 0"},
      {"cell.motion.cycles", c.motion.cycles, c.motion.cycles >= 0, "must be >= 0"},
  });
}

Status ValidateScan(const ScanOptions& s) {
  return CheckAll({
      {"scan.views", s.views, s.views > 0, "must be > 0"},
      {"scan.path_arc_deg", s.path_arc_deg, s.path_arc_deg >= 0 && s.path_arc_deg <= 360, "must be in [0, 360]"},
      {"scan.path_radius_m", s.path_radius_m, s.path_radius_m > 0 && s.path_radius_m < 3.5,
       "must be in (0, 3.5) (the floor is 8 m wide)"},
      {"scan.eye_height_m", s.eye_height_m, s.eye_height_m > 0, "must be > 0"},
      {"scan.path_center_deg", s.path_center_deg, std::isfinite(s.path_center_deg), "must be finite"},
      {"scan.path_wander_m", s.path_wander_m, s.path_wander_m >= 0 && s.path_wander_m <= 0.5, "must be in [0, 0.5]"},
      {"scan.image_width", s.image_width, s.image_width > 0 && s.image_width <= 4096, "must be in [1, 4096]"},
      {"scan.image_height", s.image_height, s.image_height > 0 && s.image_height <= 4096, "must be in [1, 4096]"},
      {"scan.fov_horizontal_deg", s.fov_horizontal_deg, s.fov_horizontal_deg > 0 && s.fov_horizontal_deg < 180,
       "must be in (0, 180)"},
      {"scan.max_range_m", s.max_range_m, s.max_range_m > 0, "must be > 0"},
      {"scan.depth_noise_m", s.depth_noise_m, s.depth_noise_m >= 0, "must be >= 0"},
      {"scan.pose_jitter_m", s.pose_jitter_m, s.pose_jitter_m >= 0, "must be >= 0"},
      {"scan.pose_jitter_deg", s.pose_jitter_deg, s.pose_jitter_deg >= 0, "must be >= 0"},
  });
}

Status ValidateFusion(const FusionOptions& f) {
  return CheckAll({
      {"fusion.triangles_per_m3", f.triangles_per_m3, f.voxel_m > 0 || f.triangles_per_m3 > 0,
       "must be > 0 unless fusion.voxel_m is set"},
      {"fusion.voxel_m", f.voxel_m, f.voxel_m == 0 || (f.voxel_m >= 0.002 && f.voxel_m <= 0.5),
       "must be 0 (derive from triangles_per_m3) or in [0.002, 0.5]"},
      {"fusion.truncation_voxels", f.truncation_voxels, f.truncation_voxels >= 1, "must be >= 1"},
      {"fusion.surface_chunk_m", f.surface_chunk_m, f.surface_chunk_m > 0, "must be > 0"},
      {"fusion.crop_radius_m", f.crop_radius_m, f.crop_radius_m > 0, "must be > 0"},
  });
}

Status ValidateOptions(const SimOptions& o) {
  ARREF_RETURN_IF_ERROR(ValidateCell(o.cell));
  ARREF_RETURN_IF_ERROR(ValidateScan(o.scan));
  ARREF_RETURN_IF_ERROR(ValidateFusion(o.fusion));
  const SeedNoise& n = o.seed_noise;
  return CheckAll({
      {"seed_noise.horizontal_sigma_m", n.horizontal_sigma_m, n.horizontal_sigma_m >= 0, "must be >= 0"},
      {"seed_noise.vertical_max_m", n.vertical_max_m, n.vertical_max_m >= 0, "must be >= 0"},
      {"seed_noise.yaw_sigma_deg", n.yaw_sigma_deg, n.yaw_sigma_deg >= 0, "must be >= 0"},
      {"seed_count", o.seed_count, o.seed_count >= 0, "must be >= 0"},
  });
}

double VoxelSize(const FusionOptions& f) {
  if (f.voxel_m > 0) return f.voxel_m;
  return std::clamp(std::sqrt(2.0 * kSurfacePerVolume / f.triangles_per_m3), kMinVoxel, kMaxVoxel);
}

}  // namespace

namespace detail {

// Counter-based Gaussian (Box-Muller on hashed uniforms): a pixel's noise depends only on
// (seed, view, pixel), never on which thread drew it first.
double HashGaussian(std::uint64_t seed, std::uint64_t view, std::uint64_t pixel) {
  const std::uint64_t h1 = SplitMix64(seed ^ SplitMix64(view ^ SplitMix64(pixel)));
  const std::uint64_t h2 = SplitMix64(h1);
  const double u1 = (static_cast<double>(h1 >> 11) + 0.5) * 0x1.0p-53;
  const double u2 = static_cast<double>(h2 >> 11) * 0x1.0p-53;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * u2);
}

void AddRangeNoise(RangeImage& range, const ScanOptions& scan, std::uint64_t seed, int view) {
  if (scan.depth_noise_m <= 0) return;
  for (std::size_t i = 0; i < range.size(); ++i) {
    if (range[i] <= 0) continue;
    const double r = range[i] + scan.depth_noise_m * HashGaussian(seed, static_cast<std::uint64_t>(view), i);
    range[i] = (r > 0 && r <= scan.max_range_m) ? static_cast<float>(r) : 0.0f;
  }
}

}  // namespace detail

namespace {

using detail::AddRangeNoise;

struct View {
  Iso3 T_cell_camera_true;      // where the depth image was taken
  Iso3 T_cell_camera_believed;  // where head tracking says it was: used for fusion
};

}  // namespace

namespace detail {
// Small head-tracking error, expressed in the camera frame.
Iso3 RandomJitter(const ScanOptions& scan, std::mt19937_64& rng) {
  std::normal_distribution<double> rot(0.0, scan.pose_jitter_deg * kDegree), pos(0.0, scan.pose_jitter_m);
  const Vec3 w(rot(rng), rot(rng), rot(rng));
  Iso3 T = Iso3::Identity();
  if (w.norm() > 0) T.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  T.translation() = Vec3(pos(rng), pos(rng), pos(rng));
  return T;
}

double SeenTolerance(const ScanOptions& scan) { return 0.02 + 3 * scan.depth_noise_m; }

std::function<Iso3(const Vec3&)> SurfaceErrors(const DeviceVariation& device, std::uint64_t rng_seed) {
  const int updates = std::max(1, device.surface_updates);
  return [=](const Vec3& p) {
    const double size = device.surface_size_m;
    const Vec3 corner = (p / size).array().floor().matrix() * size;
    return ErrorOfCube(device, corner, size, updates, rng_seed).T_moved_true;
  };
}

}  // namespace detail

namespace {

using detail::MeshImprint;
using detail::RandomJitter;
using detail::SeenTolerance;
using detail::SurfaceErrors;

// The walker circles the robot's front (+x) on an arc; what lies behind stays unseen.
std::vector<View> WalkingPath(const ScanOptions& scan, const Iso3& T_cell_base, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> aim_height(0.5, 0.8);
  std::vector<View> views;
  const double arc = scan.path_arc_deg * kDegree;
  const double spacing = scan.views == 1 ? 0.0 : arc / (scan.views - 1);
  for (int i = 0; i < scan.views; ++i) {
    double theta = scan.views == 1 ? 0.0 : -arc / 2 + arc * i / (scan.views - 1);
    double radius = scan.path_radius_m, height = scan.eye_height_m;
    if (scan.path_wander_m > 0) {  // drawn only then: the default path's views stay as they were
      std::normal_distribution<double> wander(0.0, scan.path_wander_m);
      theta += std::uniform_real_distribution<double>(-0.4, 0.4)(rng) * spacing;
      radius = std::max(0.5, radius + wander(rng));
      height += wander(rng) / 3;
    }
    theta += scan.path_center_deg * kDegree;
    const Vec3 eye(radius * std::cos(theta), radius * std::sin(theta), height);
    const Vec3 target = T_cell_base * Vec3(0, 0, aim_height(rng));
    const Iso3 believed = LookAt(eye, target);
    views.push_back({believed * RandomJitter(scan, rng), believed});
  }
  return views;
}

// HoloLens world: gravity-aligned, origin where the app started (head height), any heading.
Iso3 RandomWorldFrame(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> yaw(0.0, 2 * std::numbers::pi), horizontal(-3.0, 3.0), vertical(-1.5, 0.0);
  const double x = horizontal(rng), y = horizontal(rng), z = vertical(rng);
  return MakeYawPose(x, y, z, yaw(rng));
}

// The joints at view `view` of `views` under a mapping motion: each moving joint swings
// amplitude * sin(2 pi cycles s) round its final value, s running from 1 at the first view to 0
// at the last, so the last view sees the final joint state.
JointValues JointsAtView(const RobotModel& robot, const JointValues& final_joints, const MappingMotion& motion, int view,
                         int views) {
  JointValues q = final_joints;
  const double s = views > 1 ? static_cast<double>(views - 1 - view) / (views - 1) : 0.0;
  for (const std::string& j : motion.joints) q[j] += motion.amplitude_rad * std::sin(2 * std::numbers::pi * motion.cycles * s);
  return robot.ClampedToLimits(q);
}

// The cell as each view saw it: with a mapping motion, the robot re-posed per view (its
// vertices are the scene's first, in the same order for every joint state), else one caster.
class ViewCasters {
 public:
  ViewCasters(const CellScene& scene, const RobotModel& robot, const MappingMotion& motion, int views)
      : scene_(scene), robot_(robot), motion_(motion), views_(views) {}

  Result<const RayCaster*> At(int view) {
    const bool moving = !motion_.joints.empty() && scene_.robot_vertices > 0;
    if (caster_ && !moving) return &*caster_;
    TriangleMesh mesh = scene_.mesh;
    if (moving) {
      ARREF_ASSIGN_OR_RETURN(const TriangleMesh posed,
                             robot_.PosedMesh(JointsAtView(robot_, scene_.joints, motion_, view, views_)));
      if (posed.vertices.size() != scene_.robot_vertices) return Status::Internal("the re-posed robot changed its mesh");
      for (std::size_t i = 0; i < posed.vertices.size(); ++i)
        mesh.vertices[i] = (scene_.T_cell_base * posed.vertices[i].cast<double>()).cast<float>();
    }
    ARREF_ASSIGN_OR_RETURN(RayCaster caster, RayCaster::Create(mesh));
    caster_.emplace(std::move(caster));
    return &*caster_;
  }

 private:
  const CellScene& scene_;
  const RobotModel& robot_;
  const MappingMotion& motion_;
  int views_;
  std::optional<RayCaster> caster_;
};

// Each moving joint's range over the views (what a joint state stream sent while mapping).
JointRanges RangesWhileMapping(const RobotModel& robot, const JointValues& final_joints, const MappingMotion& motion,
                               int views) {
  JointRanges ranges;
  for (int i = 0; i < views; ++i)
    for (const std::string& j : motion.joints) {
      const double q = JointsAtView(robot, final_joints, motion, i, views).at(j);
      WidenRange(ranges, j, q, q);
    }
  return ranges;
}

// Ray casts every view from its true pose and fuses it at its believed pose, in the world
// frame: the headset's voxel grid is aligned with its world, not with the cell.
Result<TriangleMesh> ScanAndFuse(const CellScene& scene, const RobotModel& robot, const SimOptions& options,
                                 const Iso3& T_world_cell, double voxel_m, std::uint64_t rng_seed, std::mt19937_64& rng,
                                 std::vector<Vec3>* head_path_world, MeshImprint* imprint /* null: not measured */) {
  const ScanOptions& scan = options.scan;
  const PinholeCamera camera = PinholeCamera::FromFov(scan.image_width, scan.image_height, scan.fov_horizontal_deg);
  TsdfOptions tsdf;
  tsdf.voxel_m = voxel_m;
  // A band narrower than the depth noise drops the noisier half of the observations behind
  // the surface, biasing voxels positive and punching holes in fine meshes.
  tsdf.truncation_m = std::max(options.fusion.truncation_voxels * voxel_m, kNoiseSigmasInBand * scan.depth_noise_m);
  tsdf.crop_center = (T_world_cell * scene.T_cell_base).translation();
  tsdf.crop_radius_m = options.fusion.crop_radius_m;
  TsdfVolume volume(tsdf);
  const std::vector<View> views = WalkingPath(scan, scene.T_cell_base, rng);
  ViewCasters casters(scene, robot, options.cell.motion, static_cast<int>(views.size()));
  for (int i = 0; i < static_cast<int>(views.size()); ++i) {
    std::vector<float> incidence;
    ARREF_ASSIGN_OR_RETURN(const RayCaster* caster, casters.At(i));
    RangeImage range = caster->Render(camera, views[i].T_cell_camera_true, scan.max_range_m, &incidence);
    AddRangeNoise(range, scan, rng_seed, i);
    if (imprint) imprint->AddView(camera, T_world_cell * views[i].T_cell_camera_true, T_world_cell * views[i].T_cell_camera_believed,
                     range, SeenTolerance(scan));
    ARREF_RETURN_IF_ERROR(volume.Integrate(camera, T_world_cell * views[i].T_cell_camera_believed, range, incidence));
    head_path_world->push_back(T_world_cell * views[i].T_cell_camera_believed.translation());
  }
  spdlog::debug("sim: fused {} views into {} blocks of {}^3 voxels", views.size(), volume.block_count(),
                TsdfVolume::kBlock);
  return volume.ExtractMesh();
}


// Random streams of their own, one per quantity (DeviceVariation) or purpose: adding a draw to
// one leaves every other as it was, and the cell's main stream (layout, walk, seeds) untouched.
}  // namespace

namespace detail {
std::mt19937_64 Stream(std::uint64_t seed, std::uint64_t purpose) { return std::mt19937_64(SplitMix64(seed ^ SplitMix64(purpose))); }
}  // namespace detail

namespace {

using detail::Stream;

constexpr std::uint64_t kDeviceStream = 0xDE71CE;

double Uniform(std::uint64_t seed, std::uint64_t purpose, double lo, double hi) {
  auto rng = Stream(seed, purpose);
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

// How far the posed arm reaches horizontally from its base: the walker stays clear of it.
Result<double> HorizontalReach(const RobotModel& robot, const JointValues& joints) {
  auto complete = robot.CompleteJoints(joints);
  if (!complete.ok()) return complete.status();
  auto posed = robot.PosedMesh(*complete);
  if (!posed.ok()) return posed.status();
  double reach = 0;
  for (const Vec3f& v : posed->vertices) reach = std::max(reach, static_cast<double>(v.head<2>().norm()));
  return reach;
}

// The scan a device variation asks for.
Result<SimOptions> WithDevice(const RobotModel& robot, SimOptions options, const DeviceVariation& device) {
  options.scan.depth_noise_m = device.depth_noise_m;
  options.scan.path_arc_deg = device.walk_arc_deg;
  double reach = 0;
  if (options.cell.robot_present) {
    auto r = HorizontalReach(robot, options.cell.joints);
    if (!r.ok()) return r.status();
    reach = *r;
  }
  // Half a metre beyond the arm, as a person keeps from a robot; the floor is 8 m wide.
  options.scan.path_radius_m = std::clamp(std::max(device.walk_distance_m, reach + 0.5), 0.5, 3.4);
  return options;
}

// Dark or shiny spots return no depth: (cell-frame centre, radius). Half lie on the robot, where
// black covers, cables and polished flanges are common, half anywhere near it.
std::vector<std::pair<Vec3, double>> MissingPatches(const CellScene& scene, const RobotModel& robot, const SimOptions& options,
                                                    const DeviceVariation& device, std::uint64_t seed) {
  std::vector<std::pair<Vec3, double>> patches;
  if (device.missing_patches <= 0) return patches;
  auto rng = Stream(seed, 11);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  TriangleMesh robot_cell;
  if (options.cell.robot_present)
    if (auto posed = robot.PosedMesh(scene.joints); posed.ok()) robot_cell.Append(*posed, scene.T_cell_base);
  const PointCloud on_robot = robot_cell.empty() ? PointCloud{} : SampleSurface(robot_cell, 512, rng());
  const PointCloud anywhere = SampleSurface(scene.mesh, 4096, rng());
  const Vec3 base = scene.T_cell_base.translation();
  std::vector<Vec3> near;
  for (const Vec3f& p : anywhere.points)
    if ((p.cast<double>() - base).norm() < options.fusion.crop_radius_m) near.push_back(p.cast<double>());
  for (int i = 0; i < device.missing_patches; ++i) {
    const bool robot_part = !on_robot.points.empty() && unit(rng) < 0.5;
    if (!robot_part && near.empty()) continue;
    const std::size_t n = robot_part ? on_robot.points.size() : near.size();
    const auto k = std::min(n - 1, static_cast<std::size_t>(unit(rng) * static_cast<double>(n)));
    const Vec3 centre = robot_part ? on_robot.points[k].cast<double>() : near[k];
    patches.push_back({centre, device.patch_radius_max_m * (0.25 + 0.75 * unit(rng))});
  }
  return patches;
}

// Pixels that return nothing: on a missing patch, or beyond the fusion crop (which the own
// TSDF applies to its blocks).
void DropPixels(RangeImage& range, const PinholeCamera& camera, const Iso3& T_cell_camera, const Vec3& base, double crop_radius_m,
                const std::vector<std::pair<Vec3, double>>& patches) {
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      float& r = range[static_cast<std::size_t>(v) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(u)];
      if (r <= 0) continue;
      const Vec3 hit = T_cell_camera * (camera.RayDirection(u, v) * static_cast<double>(r));
      bool drop = (hit - base).norm() > crop_radius_m;
      for (const auto& [centre, radius] : patches) drop = drop || (hit - centre).squaredNorm() < radius * radius;
      if (drop) r = 0.0f;
    }
}

}  // namespace

namespace detail {
// A rigid error up to max_m and max_deg (uniform magnitudes, uniform directions) about `centre`.
Iso3 SurfaceError(const DeviceVariation& device, const Vec3& centre, std::mt19937_64& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const Vec3 axis = Vec3(g(rng), g(rng), g(rng)).normalized(), dir = Vec3(g(rng), g(rng), g(rng)).normalized();
  const double angle = device.surface_error_max_deg * kDegree * unit(rng), shift = device.surface_error_max_m * unit(rng);
  return Eigen::Translation3d(centre + shift * dir) * Eigen::AngleAxisd(angle, axis) * Eigen::Translation3d(-centre);
}

}  // namespace detail

namespace {

using detail::ErrorOfCube;
using detail::SurfaceError;

// The robot's true surface for MeshImprint (world), or nothing when it cannot be posed.
std::optional<MeshImprint> RobotImprint(const RobotModel& robot, const CellScene& scene, const Iso3& T_world_cell,
                                        std::uint64_t rng_seed) {
  auto posed = robot.PosedMesh(scene.joints);
  if (!posed.ok() || posed->empty()) return std::nullopt;
  const Iso3 T_world_base = T_world_cell * scene.T_cell_base;
  PointCloud points = SampleSurface(*posed, 2000, rng_seed);
  points.Transform(T_world_base);
  return MeshImprint(std::move(points), T_world_base.translation());
}

// The mesh error of the cell (SimulatedCell::mesh_error_add_m) and where it put the base.
void SetMeshError(const MeshImprint& imprint, const std::function<Iso3(const Vec3&)>& T_moved_true_at,
                  SimulatedCell* cell) {
  const std::optional<Iso3> T_mesh_true = imprint.Motion(T_moved_true_at);
  if (!T_mesh_true) return;  // too little of the robot seen: not measured
  cell->mesh_error_add_m = imprint.AddOf(*T_mesh_true);
  cell->T_world_base_mesh = *T_mesh_true * cell->T_world_base;
}

}  // namespace

namespace detail {

bool HasArea(const TriangleMesh& mesh) {
  for (const Triangle& t : mesh.triangles)
    if ((mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]).squaredNorm() > 0) return true;
  return false;
}


CubeError ErrorOfCube(const DeviceVariation& device, const Vec3& corner, double size, int updates, std::uint64_t rng_seed) {
  std::uint64_t key = 0;
  for (int a = 0; a < 3; ++a) key = SplitMix64(key ^ static_cast<std::uint64_t>(std::llround(corner[a] / size) + (1 << 20)));
  auto surface_rng = Stream(rng_seed ^ key, 12);
  CubeError out;
  out.time_index = static_cast<int>(surface_rng() % static_cast<std::uint64_t>(updates));
  out.T_moved_true = SurfaceError(device, corner + Vec3::Constant(size / 2), surface_rng);
  return out;
}

Result<std::vector<Surface>> MeshLikeTheDevice(const PinholeCamera& camera, const std::vector<Iso3>& T_world_camera,
                                               const std::vector<RangeImage>& ranges, const DeviceVariation& device,
                                               double max_range_m, std::uint64_t rng_seed) {
  // Update times spread over the walk's last third: the last one after the last view.
  const int n = static_cast<int>(ranges.size()), updates = std::max(1, device.surface_updates);
  std::vector<int> snapshot_after;
  for (int k = 0; k < updates; ++k)
    snapshot_after.push_back(static_cast<int>(std::floor((n - 1) * (2.0 / 3.0 + (k + 1) / (3.0 * updates)))));
  const Open3dFusion fusion{.voxel_m = device.voxel_m,
                            .truncation_m = std::max(3.0 * device.voxel_m, kNoiseSigmasInBand * device.depth_noise_m),
                            .max_range_m = max_range_m};
  ARREF_ASSIGN_OR_RETURN(const auto meshes, FuseWithOpen3d(camera, T_world_camera, ranges, fusion, snapshot_after));
  const double size = device.surface_size_m;
  const int target = std::max(1, static_cast<int>(std::lround(device.triangles_per_m3 * size * size * size)));
  const float q = static_cast<float>(device.quantisation_m);
  std::vector<Surface> surfaces;
  for (int k = 0; k < updates; ++k) {
    const double time_s = (snapshot_after[static_cast<std::size_t>(k)] + 1) * kSecondsPerView;
    for (Surface& s : SplitIntoSurfaces(meshes[static_cast<std::size_t>(k)], size, time_s)) {
      const Vec3 corner = s.T_world_surface.translation();
      const CubeError cube = ErrorOfCube(device, corner, size, updates, rng_seed);
      if (cube.time_index != k) continue;  // meshed at another time
      ARREF_ASSIGN_OR_RETURN(s.mesh, DecimateWithOpen3d(s.mesh, target));
      for (Vec3f& v : s.mesh.vertices) {
        v = ((cube.T_moved_true * (corner + v.cast<double>())) - corner).cast<float>();
        if (q > 0) v = (v / q).array().round().matrix() * q;
      }
      if (!HasArea(s.mesh)) continue;
      s.id = surfaces.size() + 1;
      surfaces.push_back(std::move(s));
    }
  }
  spdlog::debug("sim: open3d mesher: {} views, voxel {:.3f} m, {} surfaces of {:.2f} m at {} times", n, device.voxel_m,
                surfaces.size(), size, updates);
  return surfaces;
}

}  // namespace detail

namespace {

using detail::HasArea;
using detail::MeshLikeTheDevice;

// The device's mesher: ray cast like ScanAndFuse, but depth that misses dark patches, then
// meshed as the device meshes (MeshLikeTheDevice).
Result<std::vector<Surface>> ScanAndMeshOpen3d(const CellScene& scene, const RobotModel& robot, const SimOptions& options,
                                               const DeviceVariation& device, const Iso3& T_world_cell, std::uint64_t rng_seed,
                                               std::mt19937_64& rng, std::vector<Vec3>* head_path_world,
                                               MeshImprint* imprint) {
  const ScanOptions& scan = options.scan;
  const PinholeCamera camera = PinholeCamera::FromFov(scan.image_width, scan.image_height, scan.fov_horizontal_deg);
  const std::vector<View> views = WalkingPath(scan, scene.T_cell_base, rng);
  const auto patches = MissingPatches(scene, robot, options, device, rng_seed);
  ViewCasters casters(scene, robot, options.cell.motion, static_cast<int>(views.size()));
  std::vector<RangeImage> ranges;
  std::vector<Iso3> T_world_camera;
  for (int i = 0; i < static_cast<int>(views.size()); ++i) {
    ARREF_ASSIGN_OR_RETURN(const RayCaster* caster, casters.At(i));
    RangeImage range = caster->Render(camera, views[i].T_cell_camera_true, scan.max_range_m);
    AddRangeNoise(range, scan, rng_seed, i);
    DropPixels(range, camera, views[i].T_cell_camera_true, scene.T_cell_base.translation(), options.fusion.crop_radius_m, patches);
    T_world_camera.push_back(T_world_cell * views[i].T_cell_camera_believed);
    if (imprint) imprint->AddView(camera, T_world_cell * views[i].T_cell_camera_true, T_world_camera.back(), range, SeenTolerance(scan));
    ranges.push_back(std::move(range));
    head_path_world->push_back(T_world_camera.back().translation());
  }
  return MeshLikeTheDevice(camera, T_world_camera, ranges, device, scan.max_range_m, rng_seed);
}

}  // namespace

const char* MesherName(Mesher mesher) { return mesher == Mesher::kOpen3d ? "open3d" : "own"; }

Result<Mesher> ParseMesher(const std::string& name) {
  if (name == "own") return Mesher::kOwn;
  if (name == "open3d") return Mesher::kOpen3d;
  return Status::InvalidArgument("unknown mesher '" + name + "' (own, open3d)");
}

bool MesherAvailable(Mesher mesher) { return mesher == Mesher::kOwn || Open3dAvailable(); }

DeviceVariation DrawDeviceVariation(std::uint64_t rng_seed) {
  const std::uint64_t seed = SplitMix64(rng_seed ^ kDeviceStream);
  DeviceVariation d;
  d.voxel_m = Uniform(seed, 1, 0.02, 0.06);
  d.triangles_per_m3 = Uniform(seed, 2, 400.0, 2000.0);
  // HoloLens stores positions as 16-bit normalised integers scaled to the surface (about
  // 0.03 mm on 2 m); meshes re-exported in millimetres or compressed for the network are
  // coarser.
  d.quantisation_m = Uniform(seed, 3, 0.00003, 0.004);
  d.surface_size_m = Uniform(seed, 4, 1.0, 2.0);
  d.surface_updates = static_cast<int>(std::floor(Uniform(seed, 5, 2.0, 7.0)));
  d.surface_error_max_m = Uniform(seed, 6, 0.0, 0.01);
  d.surface_error_max_deg = Uniform(seed, 7, 0.0, 0.5);
  d.missing_patches = static_cast<int>(std::floor(Uniform(seed, 8, 0.0, 7.0)));
  d.patch_radius_max_m = Uniform(seed, 9, 0.05, 0.3);
  d.depth_noise_m = Uniform(seed, 10, 0.004, 0.012);
  d.walk_arc_deg = Uniform(seed, 13, 90.0, 360.0);
  d.walk_distance_m = Uniform(seed, 14, 1.0, 3.0);
  return d;
}

Status LeaveOutErrors(const std::vector<std::string>& errors, std::uint64_t rng_seed, SimOptions* options) {
  DeviceVariation device = options->fusion.device ? *options->fusion.device : DrawDeviceVariation(rng_seed);
  // Depth noise is kept small rather than 0: the fusions size their truncation band on it.
  constexpr double kQuietDepthM = 0.001, kFinestQuantisationM = 1e-5;
  for (const std::string& e : errors) {
    if (e == "view-jitter") {
      SetPoseJitter(&options->scan, 0.0);
    } else if (e == "surface-errors") {
      device.surface_error_max_m = 0.0, device.surface_error_max_deg = 0.0;
    } else if (e == "depth-noise") {
      device.depth_noise_m = kQuietDepthM, options->scan.depth_noise_m = kQuietDepthM;
    } else if (e == "patches") {
      device.missing_patches = 0;
    } else if (e == "quantisation") {
      device.quantisation_m = kFinestQuantisationM;
    } else {
      return Status::InvalidArgument("unknown device error '" + e +
                                     "' (view-jitter, surface-errors, depth-noise, patches, quantisation)");
    }
  }
  if (options->fusion.mesher == Mesher::kOpen3d) options->fusion.device = device;
  return Status::Ok();
}

const char* SeedFamilyName(SeedFamily family) {
  switch (family) {
    case SeedFamily::kUser: return "user";
    case SeedFamily::kCube: return "cube";
    case SeedFamily::kAnyYaw: return "any-yaw";
    case SeedFamily::kTruth: return "truth";
    case SeedFamily::kDefault: break;
  }
  return "default";
}

Result<SeedFamily> ParseSeedFamily(const std::string& name) {
  constexpr std::array kAll = {SeedFamily::kDefault, SeedFamily::kUser, SeedFamily::kCube, SeedFamily::kAnyYaw,
                               SeedFamily::kTruth};
  std::string known;
  for (SeedFamily f : kAll) {
    if (name == SeedFamilyName(f)) return f;
    known += (known.empty() ? "" : ", ") + std::string(SeedFamilyName(f));
  }
  return Status::InvalidArgument("unknown seed family '" + name + "' (" + known + ")");
}

void SetPoseJitter(ScanOptions* scan, double sigma_m) {
  scan->pose_jitter_m = sigma_m;
  scan->pose_jitter_deg = sigma_m * 75.0;
}

SimOptions SmallPreset() {
  SimOptions o;
  o.fusion.triangles_per_m3 = 1000.0;
  return o;
}

SimOptions BigPreset() {
  SimOptions o;
  o.fusion.triangles_per_m3 = 1240000.0;
  return o;
}

Result<SimulatedCell> SimulateCell(const RobotModel& robot, const SimOptions& requested, std::uint64_t rng_seed) {
  ARREF_RETURN_IF_ERROR(ValidateOptions(requested));
  const auto t0 = Clock::now();
  const Mesher mesher = requested.fusion.mesher;
  if (!MesherAvailable(mesher))
    return Status::FailedPrecondition("fusion.mesher = open3d: arref was built without Open3D (apt-get install "
                                      "libopen3d-dev, then re-run cmake)");
  SimOptions options = requested;
  DeviceVariation device;
  if (mesher == Mesher::kOpen3d) {
    device = requested.fusion.device.value_or(DrawDeviceVariation(rng_seed));
    auto varied = WithDevice(robot, requested, device);
    if (!varied.ok()) return varied.status().WithContext("simulating a cell of '" + robot.name() + "'");
    options = std::move(*varied);
    ARREF_RETURN_IF_ERROR(ValidateOptions(options).WithContext("the device variation"));
  }
  std::mt19937_64 rng(rng_seed);
  SimulatedCell cell;
  cell.mesher = mesher;
  cell.device = device;
  cell.T_world_cell = RandomWorldFrame(rng);
  auto scene = BuildCellScene(robot, options.cell, options.scan, rng);
  if (!scene.ok()) return scene.status().WithContext("simulating a cell of '" + robot.name() + "'");
  cell.T_world_base = cell.T_world_cell * scene->T_cell_base;
  cell.joints = scene->joints;
  cell.props = scene->props;
  if (options.cell.robot_present)
    cell.joints_while_mapping = RangesWhileMapping(robot, scene->joints, options.cell.motion, options.scan.views);
  std::size_t triangles = 0;
  std::optional<MeshImprint> imprint = RobotImprint(robot, *scene, cell.T_world_cell, rng_seed);
  if (mesher == Mesher::kOpen3d) {
    cell.voxel_m = device.voxel_m;
    auto surfaces = ScanAndMeshOpen3d(*scene, robot, options, device, cell.T_world_cell, rng_seed, rng,
                                      &cell.head_path_world, imprint ? &*imprint : nullptr);
    if (!surfaces.ok()) return surfaces.status().WithContext("simulating the headset's scan (open3d mesher)");
    cell.surfaces = std::move(*surfaces);
    for (const Surface& s : cell.surfaces) triangles += s.mesh.triangles.size();
    if (imprint) SetMeshError(*imprint, SurfaceErrors(device, rng_seed), &cell);
  } else {
    cell.voxel_m = VoxelSize(options.fusion);
    auto fused = ScanAndFuse(*scene, robot, options, cell.T_world_cell, cell.voxel_m, rng_seed, rng, &cell.head_path_world,
                             imprint ? &*imprint : nullptr);
    if (!fused.ok()) return fused.status().WithContext("simulating the headset's scan");
    triangles = fused->triangles.size();
    cell.surfaces = SplitIntoSurfaces(*fused, options.fusion.surface_chunk_m, options.scan.views * kSecondsPerView);
    if (imprint) SetMeshError(*imprint, {}, &cell);
  }
  if (triangles == 0)
    return Status::FailedPrecondition("simulated scan saw nothing within fusion.crop_radius_m = " +
                                      std::to_string(options.fusion.crop_radius_m) + " of the robot base");
  cell.truth_world.Append(scene->mesh, cell.T_world_cell);
  cell.seeds = DrawSeeds(cell.T_world_base, options.seed_noise, options.seed_count, rng);
  spdlog::debug("sim: seed {}: {} triangles in {} surfaces, voxel {:.3f} m, {:.2f} s", rng_seed, triangles,
                cell.surfaces.size(), cell.voxel_m, SecondsSince(t0));
  return cell;
}

std::vector<Iso3> DrawSeeds(const Iso3& T_world_base, const SeedNoise& noise, int count, std::mt19937_64& rng) {
  if (noise.family == SeedFamily::kTruth) return std::vector<Iso3>(static_cast<std::size_t>(std::max(count, 0)), T_world_base);
  std::normal_distribution<double> horizontal(0.0, noise.horizontal_sigma_m), yaw_error(0.0, noise.yaw_sigma_deg * kDegree);
  std::uniform_real_distribution<double> vertical(0.0, noise.vertical_max_m);
  const Vec3 base = T_world_base.translation();
  const double yaw = YawOf(T_world_base);
  std::vector<Iso3> seeds;
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  if (noise.family != SeedFamily::kDefault) {
    std::normal_distribution<double> user_yaw(0.0, 15.0 * kDegree);
    for (int i = 0; i < count; ++i) {
      Vec3 d;
      if (noise.family == SeedFamily::kCube) {
        d = Vec3(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5);  // a 1 m cube
      } else {
        const double r = 0.1 + 0.2 * unit(rng), a = 2 * std::numbers::pi * unit(rng);
        d = Vec3(r * std::cos(a), r * std::sin(a), 0.6 * unit(rng) - 0.3);
      }
      const double dyaw = noise.family == SeedFamily::kAnyYaw ? std::numbers::pi * (2 * unit(rng) - 1) : user_yaw(rng);
      seeds.push_back(MakeYawPose(base.x() + d.x(), base.y() + d.y(), base.z() + d.z(), yaw + dyaw));
    }
    return seeds;
  }
  for (int i = 0; i < count; ++i) {
    double dx = horizontal(rng), dy = horizontal(rng);
    if (noise.max_horizontal_m > 0) {  // uniform in the disc: radius ~ sqrt(u)
      const double r = noise.max_horizontal_m * std::sqrt(unit(rng)), a = 2 * std::numbers::pi * unit(rng);
      dx = r * std::cos(a);
      dy = r * std::sin(a);
    }
    const double dz = vertical(rng);
    const double dyaw = noise.any_yaw ? std::numbers::pi * (2 * unit(rng) - 1) : yaw_error(rng);
    seeds.push_back(MakeYawPose(base.x() + dx, base.y() + dy, base.z() + dz, yaw + dyaw));
  }
  return seeds;
}

}  // namespace arref::sim
