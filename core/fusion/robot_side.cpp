#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "arref/base/clock.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/fusion/model_visibility.h"
#include "arref/fusion/robot_side.h"
#include "arref/robot/joint_motion.h"
#include "arref/scene/sampling.h"

namespace arref {
namespace {
// The side a user maps walking round a robot: 216 degrees, with eyes 9 degrees apart. Walks
// centred 45 degrees apart and the all-round circle then put their eyes on one lattice of 40
// azimuths, so the nine surfaces of a joint state need 40 renders, not 9 x 24 (MakeMany).
constexpr double kWalkArcDeg = 216.0;
constexpr double kEyeStepDeg = 9.0;
constexpr double kRefitArcDeg = 220.0;
// Mapped triangles this near the robot's exact surface are the robot's own (its fused shell
// lies up to ~4 cm off it under overhangs), not other objects.
constexpr double kContextClearanceM = 0.05;

Status CheckWalk(int walk) {
  if (walk < -1 || walk >= RobotSide::kWalks) return Status::InvalidArgument(fmt::format("no walk {} round the robot", walk));
  return Status::Ok();
}

// A walk's eyes (walk -1: all round): `eyes` of them on the arc, or on the circle.
ReconstructionOptions EyesOf(double voxel_m, int walk, double arc_deg, int eyes_on_arc, int eyes_round) {
  ReconstructionOptions options;
  options.voxel_m = voxel_m;
  options.azimuths = eyes_round;
  if (walk >= 0)
    options.arc_deg = arc_deg, options.arc_center_deg = 360.0 * walk / RobotSide::kWalks, options.azimuths = eyes_on_arc;
  return options;
}

ReconstructionOptions WalkOptions(double voxel_m, int walk) {
  const auto on_lattice = [](double deg) { return static_cast<int>(std::lround(deg / kEyeStepDeg)); };
  return EyesOf(voxel_m, walk, kWalkArcDeg, on_lattice(kWalkArcDeg) + 1, on_lattice(360.0));
}

// The refit's eyes, per request: 24 on a 220-degree arc, not the walks' 25 lattice eyes, which
// fitted no better and worse on the simulator's regular arc (docs/engine.md, "Refit in context").
ReconstructionOptions RefitOptions(double voxel_m, int walk) { return EyesOf(voxel_m, walk, kRefitArcDeg, 24, 24); }
}  // namespace

RobotSide::RobotSide(TriangleMesh mesh_base, PointCloud samples, std::uint64_t seed, bool partial, double resting_height)
    : mesh_base_(std::move(mesh_base)),
      samples_(std::move(samples)),
      seed_(seed),
      partial_(partial),
      resting_height_(resting_height) {}

Result<PointCloud> SamplePosedRobot(const TriangleMesh& mesh_base, const std::string& name, std::size_t samples,
                                    std::uint64_t seed) {
  if (mesh_base.empty()) return Status::FailedPrecondition("robot '" + name + "' has no geometry to register");
  PointCloud cloud = SampleSurface(mesh_base, samples, seed);
  auto visibility = ModelVisibility(mesh_base, cloud);
  if (!visibility.ok()) return visibility.status().WithContext("robot '" + name + "'");
  cloud.visibility = std::move(visibility).value();
  return cloud;
}

Result<PointCloud> SampleRobot(const RobotModel& robot, const JointValues& joints, std::size_t samples,
                               std::uint64_t seed) {
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh mesh, robot.PosedMesh(joints));
  return SamplePosedRobot(mesh, robot.name(), samples, seed);
}

Result<std::shared_ptr<const RobotSide>> RobotSide::Create(const RobotModel& robot, const JointValues& joints,
                                                           std::size_t samples, std::uint64_t seed,
                                                           const std::set<std::string>* links) {
  ARREF_ASSIGN_OR_RETURN(TriangleMesh mesh, links ? robot.PosedMesh(joints, *links) : robot.PosedMesh(joints));
  ARREF_ASSIGN_OR_RETURN(PointCloud cloud, SamplePosedRobot(mesh, robot.name(), samples, seed));
  const bool partial = links && links->size() < robot.GeometryLinks().size();
  ARREF_ASSIGN_OR_RETURN(const double resting_height, RestingHeight(robot));
  return std::shared_ptr<const RobotSide>(
      new RobotSide(std::move(mesh), std::move(cloud), seed, partial, resting_height));
}

Result<std::shared_ptr<const PointCloud>> RobotSide::Expected(double voxel_m, int walk, std::size_t thinned_to,
                                                              const CancelToken* cancel) const {
  ARREF_RETURN_IF_ERROR(CheckWalk(walk));
  // Meshes a fraction of a millimetre apart fuse alike.
  const ExpectedKey key{std::lround(voxel_m * 1000), walk, thinned_to};
  // Built under the lock: concurrent requests for the same voxel wait for one build.
  std::lock_guard lock(mutex_);
  auto surface = ExpectedLocked(key, cancel);
  // A cancelled build keeps nothing, so it must not push out a voxel size that holds surfaces.
  if (surface.status().code() != StatusCode::kCancelled) KeepRecentVoxelSizes(std::get<0>(key));
  return surface;
}

std::size_t RobotSide::voxel_sizes_kept() const {
  std::lock_guard lock(mutex_);
  return voxel_sizes_mm_.size();
}

void RobotSide::KeepRecentVoxelSizes(long used_mm) const {
  std::erase(voxel_sizes_mm_, used_mm);
  voxel_sizes_mm_.push_back(used_mm);
  while (voxel_sizes_mm_.size() > kVoxelSizesKept) {
    const long dropped = voxel_sizes_mm_.front();
    voxel_sizes_mm_.erase(voxel_sizes_mm_.begin());
    std::erase_if(expected_, [&](const auto& entry) { return std::get<0>(entry.first) == dropped; });
    std::erase_if(failed_, [&](const auto& entry) { return std::get<0>(entry.first) == dropped; });
    spdlog::debug("expected robot surfaces at {} mm voxels dropped from the cache (at most {} voxel sizes kept)", dropped,
                  kVoxelSizesKept);
  }
}

Result<std::shared_ptr<const PointCloud>> RobotSide::ExpectedLocked(const ExpectedKey& key,
                                                                    const CancelToken* cancel) const {
  if (auto it = expected_.find(key); it != expected_.end()) return it->second;
  const auto [voxel_mm, walk, thinned_to] = key;
  if (thinned_to > 0) {  // thinned from the whole surface, once
    ARREF_ASSIGN_OR_RETURN(const auto whole, ExpectedLocked({voxel_mm, walk, 0}, cancel));
    return expected_.emplace(key, std::make_shared<const PointCloud>(Thinned(*whole, thinned_to))).first->second;
  }
  if (auto it = failed_.find(key); it != failed_.end()) return it->second;
  ARREF_RETURN_IF_ERROR(MakeEveryWalk(voxel_mm, cancel));
  if (auto it = failed_.find(key); it != failed_.end()) return it->second;
  if (auto it = expected_.find(key); it != expected_.end()) return it->second;
  return Status::Internal(fmt::format("expected surface at {} mm, walk {}: neither made nor failed", voxel_mm, walk));
}

// The walk choice lays every walk's surface on the scene, so all of them are made together:
// they share most eyes. A walk's failure is kept, so that asking again does not remake them all.
Status RobotSide::MakeEveryWalk(long voxel_mm, const CancelToken* cancel) const {
  const auto t0 = SteadyClock::now();
  auto maker = Maker();
  std::vector<ReconstructionOptions> options;
  for (int walk = -1; walk < kWalks; ++walk) options.push_back(WalkOptions(voxel_mm / 1000.0, walk));
  auto clouds = maker.ok() ? (*maker)->MakeMany(options, samples_.size(), cancel)
                           : std::vector<Result<PointCloud>>(options.size(), maker.status());
  // A cancel is the request's, not the surfaces': kept, it would fail the next request too.
  for (const auto& cloud : clouds)
    if (cloud.status().code() == StatusCode::kCancelled) return cloud.status();
  for (int walk = -1; walk < kWalks; ++walk) {
    auto& cloud = clouds[static_cast<std::size_t>(walk + 1)];
    const ExpectedKey key{voxel_mm, walk, 0};
    if (cloud.ok())
      expected_.emplace(key, std::make_shared<const PointCloud>(std::move(*cloud)));
    else
      failed_.emplace(key, cloud.status());
  }
  spdlog::debug("expected robot surfaces at {} mm voxels, all round and {} walks: {:.0f} ms", voxel_mm, kWalks,
                MsSince(t0));
  return Status::Ok();
}

std::shared_ptr<const PointCloud> RobotSide::Visible(std::size_t thinned_to) const {
  std::lock_guard lock(mutex_);
  auto& kept = visible_[thinned_to];
  if (!kept) kept = std::make_shared<const PointCloud>(Thinned(VisiblePoints(samples_), thinned_to));
  return kept;
}

Result<std::shared_ptr<const ExpectedSurfaceMaker>> RobotSide::Maker() const {
  if (!maker_) {
    ARREF_ASSIGN_OR_RETURN(ExpectedSurfaceMaker maker, ExpectedSurfaceMaker::Create(mesh_base_, seed_));
    maker_ = std::make_shared<const ExpectedSurfaceMaker>(std::move(maker));
  }
  return maker_;
}

std::vector<Vec3> RobotSide::RefitEyes(int walk) { return EyePositions(RefitOptions(0.0, walk)); }

Result<PointCloud> RobotSide::ExpectedInContext(double voxel_m, int walk, const TriangleMesh& scene_world,
                                                const Iso3& T_world_base, const std::vector<Vec3>& eyes_base,
                                                const CancelToken* cancel) const {
  ARREF_RETURN_IF_ERROR(CheckWalk(walk));
  std::shared_ptr<const ExpectedSurfaceMaker> maker;
  {
    std::lock_guard lock(mutex_);
    ARREF_ASSIGN_OR_RETURN(maker, Maker());
  }
  const double clearance = std::max(kContextClearanceM, 1.5 * voxel_m);
  ReconstructionOptions options = RefitOptions(voxel_m, walk);
  // Made on every request, so at one pixel per voxel: half the time at the same accuracy; fewer
  // eyes than 24 lose accuracy (docs/engine.md, "Refit in context").
  options.pixels_per_voxel = 1.0;
  for (const Vec3& eye : eyes_base) options.eyes_base.push_back({eye.x(), eye.y(), eye.z()});
  return maker->MakeInContext(options, samples_.size(), scene_world, T_world_base, clearance, cancel);
}

}  // namespace arref
