#include "arref/sim/cell_simulator.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <sstream>
#include <string>
#include <tuple>

#include "arref/fusion/raycaster.h"
#include "scene_builder.h"
#include "arref/fusion/tsdf.h"

namespace arref::sim {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;
// Surface area per cubic metre of a mapped cell (floor, walls, robot, furniture in the 2 m
// sphere). Surface nets emits ~2 triangles per voxel face of surface, so a density of
// triangles_per_m3 needs voxels of sqrt(2 * kSurfacePerVolume / triangles_per_m3).
constexpr double kSurfacePerVolume = 0.6;
constexpr double kMinVoxel = 0.01;  // finer gains nothing at 8 mm depth noise and costs memory
constexpr double kMaxVoxel = 0.05;
constexpr double kNoiseSigmasInBand = 6.0;
// Long-throw depth runs at a few frames per second: time between the path's views.
constexpr double kSecondsPerView = 0.5;

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

std::uint64_t SplitMix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

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

struct View {
  Iso3 T_cell_camera_true;      // where the depth image was taken
  Iso3 T_cell_camera_believed;  // where head tracking says it was: used for fusion
};

// Small head-tracking error, expressed in the camera frame.
Iso3 RandomJitter(const ScanOptions& scan, std::mt19937_64& rng) {
  std::normal_distribution<double> rot(0.0, scan.pose_jitter_deg * kDeg), pos(0.0, scan.pose_jitter_m);
  const Vec3 w(rot(rng), rot(rng), rot(rng));
  Iso3 T = Iso3::Identity();
  if (w.norm() > 0) T.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  T.translation() = Vec3(pos(rng), pos(rng), pos(rng));
  return T;
}

// The walker circles the robot's front (+x) on an arc; what lies behind stays unseen.
std::vector<View> WalkingPath(const ScanOptions& scan, const Iso3& T_cell_base, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> aim_height(0.5, 0.8);
  std::vector<View> views;
  const double arc = scan.path_arc_deg * kDeg;
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
    theta += scan.path_center_deg * kDeg;
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

// Ray casts every view from its true pose and fuses it at its believed pose, in the world
// frame: the headset's voxel grid is aligned with its world, not with the cell.
Result<TriangleMesh> ScanAndFuse(const CellScene& scene, const SimOptions& options, const Iso3& T_world_cell,
                                 double voxel_m, std::uint64_t rng_seed, std::mt19937_64& rng,
                                 std::vector<Vec3>* head_path_world) {
  const ScanOptions& scan = options.scan;
  auto caster = RayCaster::Create(scene.mesh);
  if (!caster.ok()) return caster.status();
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
  for (int i = 0; i < static_cast<int>(views.size()); ++i) {
    std::vector<float> incidence;
    RangeImage range = caster->Render(camera, views[i].T_cell_camera_true, scan.max_range_m, &incidence);
    AddRangeNoise(range, scan, rng_seed, i);
    ARREF_RETURN_IF_ERROR(volume.Integrate(camera, T_world_cell * views[i].T_cell_camera_believed, range, incidence));
    head_path_world->push_back(T_world_cell * views[i].T_cell_camera_believed.translation());
  }
  spdlog::debug("sim: fused {} views into {} blocks of {}^3 voxels", views.size(), volume.block_count(),
                TsdfVolume::kBlock);
  return volume.ExtractMesh();
}

}  // namespace

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

Result<SimulatedCell> SimulateCell(const RobotModel& robot, const SimOptions& options, std::uint64_t rng_seed) {
  ARREF_RETURN_IF_ERROR(ValidateOptions(options));
  const auto t0 = Clock::now();
  std::mt19937_64 rng(rng_seed);
  SimulatedCell cell;
  cell.T_world_cell = RandomWorldFrame(rng);
  auto scene = BuildCellScene(robot, options.cell, options.scan, rng);
  if (!scene.ok()) return scene.status().WithContext("simulating a cell of '" + robot.name() + "'");
  cell.T_world_base = cell.T_world_cell * scene->T_cell_base;
  cell.joints = scene->joints;
  cell.props = scene->props;
  cell.voxel_m = VoxelSize(options.fusion);

  auto fused = ScanAndFuse(*scene, options, cell.T_world_cell, cell.voxel_m, rng_seed, rng, &cell.head_path_world);
  if (!fused.ok()) return fused.status().WithContext("simulating the headset's scan");
  if (fused->empty())
    return Status::FailedPrecondition("simulated scan saw nothing within fusion.crop_radius_m = " +
                                      std::to_string(options.fusion.crop_radius_m) + " of the robot base");
  cell.surfaces = SplitIntoSurfaces(*fused, options.fusion.surface_chunk_m, options.scan.views * kSecondsPerView);
  cell.truth_world.Append(scene->mesh, cell.T_world_cell);
  cell.seeds = DrawSeeds(cell.T_world_base, options.seed_noise, options.seed_count, rng);
  spdlog::debug("sim: seed {}: {} triangles in {} surfaces, voxel {:.3f} m, {:.2f} s", rng_seed,
                fused->triangles.size(), cell.surfaces.size(), cell.voxel_m, SecondsSince(t0));
  return cell;
}

std::vector<Iso3> DrawSeeds(const Iso3& T_world_base, const SeedNoise& noise, int count, std::mt19937_64& rng) {
  std::normal_distribution<double> horizontal(0.0, noise.horizontal_sigma_m), yaw_error(0.0, noise.yaw_sigma_deg * kDeg);
  std::uniform_real_distribution<double> vertical(0.0, noise.vertical_max_m);
  const Vec3 base = T_world_base.translation();
  const double yaw = YawOf(T_world_base);
  std::vector<Iso3> seeds;
  std::uniform_real_distribution<double> unit(0.0, 1.0);
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
