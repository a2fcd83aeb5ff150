#include "arref/fusion/model_reconstruction.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "arref/base/stats.h"
#include "arref/fusion/model_visibility.h"
#include "arref/scene/nearest_neighbor.h"
#include "arref/fusion/raycaster.h"
#include "arref/scene/sampling.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/fusion/tsdf.h"

namespace arref {
namespace {

Status CheckOptions(const ReconstructionOptions& o) {
  if (!(o.voxel_m >= 0.002 && o.voxel_m <= 0.5))
    return Status::InvalidArgument(fmt::format("expected surface: voxel {} m is outside [0.002, 0.5] m", o.voxel_m));
  if (!(o.truncation_voxels >= 1)) return Status::InvalidArgument("expected surface: truncation must be >= 1 voxel");
  if (!(o.arc_deg > 0 && o.arc_deg <= 360) || !std::isfinite(o.arc_center_deg))
    return Status::InvalidArgument(fmt::format("expected surface: arc {} deg must be in (0, 360]", o.arc_deg));
  if (o.azimuths < 1 || !(o.pixels_per_voxel > 0) || !(o.distance_m > 0) || !(o.fov_horizontal_deg > 0 && o.fov_horizontal_deg < 170))
    return Status::InvalidArgument("expected surface: needs eye positions and an image size");
  return Status::Ok();
}

// The triangles whose bounds overlap the box (a triangle larger than the box is kept too).
TriangleMesh TrianglesInBox(const TriangleMesh& mesh, const Aabb& box) {
  return KeepTriangles(mesh, [&](const Triangle& t) {
    Aabb bounds;
    for (std::uint32_t v : t) bounds.Extend(mesh.vertices[v]);
    return bounds.Overlaps(box);
  });
}

}  // namespace

struct ExpectedSurfaceMaker::View {
  RangeImage range;
  std::vector<float> incidence;
  std::vector<Eigen::Vector3i> band;  // its TsdfVolume::BandBlocks, when several volumes fuse it
};

struct ExpectedSurfaceMaker::Rig {
  PinholeCamera camera;
  double max_range;
  std::vector<Iso3> T_base_cameras;
  TsdfOptions volume;  // that fuses the images
};

struct ExpectedSurfaceMaker::Parts {
  RayCaster caster;  // of the robot on its floor (WithFloor)
  PointIndex robot;  // dense samples of the exact surface: which fused triangles are robot
  Aabb box;
  std::uint64_t seed;
};

ExpectedSurfaceMaker::ExpectedSurfaceMaker(std::unique_ptr<Parts> parts) : parts_(std::move(parts)) {}
ExpectedSurfaceMaker::ExpectedSurfaceMaker(ExpectedSurfaceMaker&&) noexcept = default;
ExpectedSurfaceMaker& ExpectedSurfaceMaker::operator=(ExpectedSurfaceMaker&&) noexcept = default;
ExpectedSurfaceMaker::~ExpectedSurfaceMaker() = default;

Result<ExpectedSurfaceMaker> ExpectedSurfaceMaker::Create(const TriangleMesh& robot_base, std::uint64_t seed) {
  if (robot_base.empty()) return Status::InvalidArgument("expected surface: the robot has no geometry");
  auto caster = RayCaster::Create(WithFloor(robot_base));
  if (!caster.ok()) return caster.status().WithContext("expected surface");
  return ExpectedSurfaceMaker(std::make_unique<Parts>(
      Parts{std::move(*caster), PointIndex(SampleSurface(robot_base, 20000, seed).points), BoundsOf(robot_base.vertices),
            seed}));
}

// The TSDF round the robot: its bounding sphere and the truncation band beyond it.
TsdfOptions ExpectedSurfaceMaker::Volume(const ReconstructionOptions& o) const {
  TsdfOptions tsdf;
  tsdf.voxel_m = o.voxel_m;
  tsdf.truncation_m = std::max(o.truncation_voxels * o.voxel_m, o.min_truncation_m);
  tsdf.crop_center = ((parts_->box.min + parts_->box.max) / 2).cast<double>();
  tsdf.crop_radius_m = 0.5 * (parts_->box.max - parts_->box.min).norm() + 2 * tsdf.truncation_m;
  // Only the band round the robot: its shell lies within the truncation of its surface, and a
  // cell beyond needs one voxel more. The floor and objects farther off cost time, change nothing.
  tsdf.near_points = &parts_->robot.points();
  tsdf.near_margin_m = tsdf.truncation_m + 2 * o.voxel_m;
  // Of those blocks, only the band's voxels (VoxelRows): about half of theirs round a robot's
  // links, the same shell (test ExpectedSurface.BandVoxelsFuseAsTheWholeBlocksDo).
  tsdf.near_voxels_only = true;
  tsdf.single_precision = true;  // made per request: the speed counts, and no simulator must match it
  return tsdf;
}

// A box round the band that the fusion keeps (Volume), one voxel more.
Aabb ExpectedSurfaceMaker::Band(const ReconstructionOptions& options) const {
  return parts_->box.Grown(static_cast<float>(Volume(options).near_margin_m + options.voxel_m));
}

// The eyes of a walk: one camera on an arc round the robot, each looking at its centre.
std::vector<Vec3> EyePositions(const ReconstructionOptions& o) {
  std::vector<Vec3> eyes;
  for (const auto& eye : o.eyes_base) eyes.emplace_back(eye[0], eye[1], eye[2]);
  if (!o.eyes_base.empty()) return eyes;
  // A full circle has no ends: its eyes are spread without doubling the first.
  const double step = o.arc_deg >= 360 ? 360.0 / o.azimuths : o.arc_deg / std::max(1, o.azimuths - 1);
  const double first = o.arc_deg >= 360 ? 0.0 : -o.arc_deg / 2;
  for (int a = 0; a < o.azimuths; ++a) {
    // In [0, 360) degrees: walks whose arcs share an azimuth get the same eye bit for bit
    // (MakeMany renders it once).
    double degrees = std::fmod(o.arc_center_deg + first + step * a, 360.0);
    if (degrees < 0) degrees += 360.0;
    const double azimuth = degrees * std::numbers::pi / 180;
    eyes.emplace_back(o.distance_m * std::cos(azimuth), o.distance_m * std::sin(azimuth), o.eye_height_m);
  }
  return eyes;
}

ExpectedSurfaceMaker::Rig ExpectedSurfaceMaker::Eyes(const ReconstructionOptions& o) const {
  const TsdfOptions tsdf = Volume(o);
  const double image_width_m = 2 * o.distance_m * std::tan(o.fov_horizontal_deg * std::numbers::pi / 360);
  const int width = std::clamp(static_cast<int>(std::ceil(image_width_m / o.voxel_m * o.pixels_per_voxel)), 64, 2048);
  Rig rig{PinholeCamera::FromFov(width, width * 9 / 10, o.fov_horizontal_deg),
          o.distance_m + 2 * tsdf.crop_radius_m + o.eye_height_m, {}, tsdf};
  for (const Vec3& eye : EyePositions(o)) rig.T_base_cameras.push_back(LookAt(eye, tsdf.crop_center));
  return rig;
}

ExpectedSurfaceMaker::View ExpectedSurfaceMaker::Render(const Rig& rig, std::size_t eye) const {
  View view;
  view.range = parts_->caster.Render(rig.camera, rig.T_base_cameras[eye], rig.max_range, &view.incidence);
  return view;
}

// The robot alone: its images and their bands as MakeMany shares them.
Result<TriangleMesh> ExpectedSurfaceMaker::Fuse(const Rig& rig, const std::vector<const View*>& robot_views,
                                                const CancelToken* cancel) const {
  TsdfVolume volume(rig.volume);
  std::vector<TsdfVolume::Image> images;
  for (std::size_t a = 0; a < rig.T_base_cameras.size(); ++a)
    images.push_back({rig.T_base_cameras[a], &robot_views[a]->range, &robot_views[a]->incidence, &robot_views[a]->band});
  ARREF_RETURN_IF_ERROR(volume.IntegrateAll(rig.camera, images, cancel));
  return volume.ExtractMesh();
}

// The robot with the objects round it: scene holds both.
Result<TriangleMesh> ExpectedSurfaceMaker::FuseInContext(const Rig& rig, const RayCaster& scene,
                                                         const CancelToken* cancel) const {
  TsdfVolume volume(rig.volume);
  const std::vector<View> views = ViewsInContext(rig, scene, volume, cancel);
  if (Cancelled(cancel)) return Status::Cancelled("expected surface in context: cancelled while rendering");
  std::vector<TsdfVolume::Image> images;
  for (std::size_t a = 0; a < views.size(); ++a) images.push_back({rig.T_base_cameras[a], &views[a].range, &views[a].incidence});
  ARREF_RETURN_IF_ERROR(volume.IntegrateAll(rig.camera, images, cancel));
  return volume.ExtractMesh();
}

// Every eye's image with the objects, all eyes at once: which pixels to trace depends on the
// volume's band, not on what earlier eyes allocated in it. Pixels whose rays miss the band
// change no voxel of it, so they are not traced (exact).
std::vector<ExpectedSurfaceMaker::View> ExpectedSurfaceMaker::ViewsInContext(const Rig& rig, const RayCaster& scene,
                                                                             const TsdfVolume& volume,
                                                                             const CancelToken* cancel) const {
  std::vector<View> views(rig.T_base_cameras.size());
  // Each eye polls the token before it renders: once cancelled, the images left are skipped
  // (FuseInContext then fuses none of them).
  tbb::parallel_for(std::size_t{0}, views.size(), [&](std::size_t a) {
    if (Cancelled(cancel)) return;
    const PixelMask traced = volume.NearPixels(rig.camera, rig.T_base_cameras[a]);
    views[a].range = scene.Render(rig.camera, rig.T_base_cameras[a], rig.max_range, &views[a].incidence, &traced);
  });
  return views;
}

// The fused triangles that belong to the robot: nearer to its surface than to the floor and
// to the other objects.
TriangleMesh ExpectedSurfaceMaker::RobotPart(const TriangleMesh& fused, const PointIndex* context) const {
  const float floor_z = FloorHeight(parts_->box);
  return KeepTriangles(fused, [&](const Triangle& t) {
    const Vec3f c = Centroid(fused, t);
    const float floor_sq = (c.z() - floor_z) * (c.z() - floor_z);
    // Nearer to the floor than to the robot: no object can change that, so the objects are
    // asked only about the others.
    if (!parts_->robot.AnyWithin(c, floor_sq)) return false;
    std::uint32_t i;
    float object_sq;
    if (!context || !context->NearestWithin(c, floor_sq, &i, &object_sq)) return true;
    return parts_->robot.AnyWithin(c, object_sq);
  });
}

Result<PointCloud> ExpectedSurfaceMaker::Make(const ReconstructionOptions& options, std::size_t samples) const {
  return std::move(MakeMany({options}, samples).front());
}

Result<PointCloud> ExpectedSurfaceMaker::MakeInContext(const ReconstructionOptions& options, std::size_t samples,
                                                       const TriangleMesh& scene_world, const Iso3& T_world_base,
                                                       double clearance_m, const CancelToken* cancel) const {
  const TriangleMesh context_base = Context(scene_world, T_world_base, clearance_m);
  if (context_base.empty()) return std::move(MakeMany({options}, samples, cancel).front());
  if (Cancelled(cancel)) return Status::Cancelled("expected surface in context: cancelled");
  // Robot and objects are traced as one scene, once per pixel; the robot through the BVH it
  // keeps (an Embree instance), so only the objects' is built per request.
  auto caster = RayCaster::Create(context_base, RayCaster::Build::kForOneUse, parts_->caster);
  if (!caster.ok()) return caster.status().WithContext("expected surface in context");
  std::vector<Vec3f> near = FusedPart(context_base, options);
  if (near.empty()) return Sample(options, *caster, nullptr, samples, cancel);  // objects that only hide the robot
  const PointIndex context(std::move(near));
  return Sample(options, *caster, &context, samples, cancel);
}

// Points on the objects in the fused band round the robot, where they can border its shell: two
// per voxel face, so big triangles are covered as well as a headset's small ones.
std::vector<Vec3f> ExpectedSurfaceMaker::FusedPart(const TriangleMesh& context_base,
                                                   const ReconstructionOptions& options) const {
  const TriangleMesh inside = TrianglesInBox(context_base, Band(options));
  if (inside.empty()) return {};
  const double per_m2 = 2 / (options.voxel_m * options.voxel_m);
  const auto count = static_cast<std::size_t>(std::clamp(per_m2 * inside.SurfaceArea(), 1.0, 200000.0));
  return SampleSurface(inside, count, parts_->seed).points;
}

TriangleMesh ExpectedSurfaceMaker::Context(const TriangleMesh& scene_world, const Iso3& T_world_base,
                                           double clearance_m) const {
  TriangleMesh base;
  base.Append(scene_world, T_world_base.inverse());
  const float clear_sq = static_cast<float>(clearance_m * clearance_m);
  const Aabb near_robot = parts_->box.Grown(static_cast<float>(clearance_m));
  return KeepTriangles(base, [&](const Triangle& t) {
    const Vec3f c = Centroid(base, t);
    if (!near_robot.Contains(c)) return true;
    return !parts_->robot.AnyWithin(c, clear_sq);
  });
}

Result<PointCloud> ExpectedSurfaceMaker::Sample(const ReconstructionOptions& options, const RayCaster& scene,
                                                const PointIndex* context, std::size_t samples,
                                                const CancelToken* cancel) const {
  ARREF_RETURN_IF_ERROR(CheckOptions(options));
  return SampleFused(options, FuseInContext(Eyes(options), scene, cancel), context, samples);
}

Result<PointCloud> ExpectedSurfaceMaker::SampleFused(const ReconstructionOptions& options, Result<TriangleMesh> fused,
                                                     const PointIndex* context, std::size_t samples) const {
  if (!fused.ok()) return fused.status().WithContext("expected surface");
  const TriangleMesh robot = RobotPart(*fused, context);
  if (robot.empty())
    return Status::FailedPrecondition(
        fmt::format("expected surface: nothing of the robot survives fusion at {} m voxels", options.voxel_m));
  return SampleSurface(robot, samples, parts_->seed);
}

std::vector<Result<PointCloud>> ExpectedSurfaceMaker::MakeMany(const std::vector<ReconstructionOptions>& options,
                                                               std::size_t samples, const CancelToken* cancel) const {
  const auto cancelled = [&] {
    return std::vector<Result<PointCloud>>(options.size(), Status::Cancelled("expected surfaces: cancelled"));
  };
  std::vector<Result<PointCloud>> clouds;
  std::vector<Rig> rigs;  // of the options that make sense; the others fail alone
  std::vector<std::size_t> rig_of_options;
  for (const ReconstructionOptions& o : options) {
    const Status checked = CheckOptions(o);
    clouds.push_back(checked.ok() ? Result<PointCloud>(PointCloud{}) : Result<PointCloud>(checked));
    rig_of_options.push_back(rigs.size());
    if (checked.ok()) rigs.push_back(Eyes(o));
  }
  // Every distinct eye once; equal means bit for bit, so a shared eye's image is the one each
  // rig would have rendered on its own.
  const auto same_eye = [](const Rig& a, std::size_t eye_a, const Rig& b, std::size_t eye_b) {
    return a.camera.width == b.camera.width && a.camera.height == b.camera.height &&
           a.camera.focal_px == b.camera.focal_px && a.max_range == b.max_range &&
           a.T_base_cameras[eye_a].matrix() == b.T_base_cameras[eye_b].matrix() &&
           a.volume.voxel_m == b.volume.voxel_m && a.volume.truncation_m == b.volume.truncation_m &&
           a.volume.crop_center == b.volume.crop_center && a.volume.crop_radius_m == b.volume.crop_radius_m;
  };
  std::vector<std::pair<const Rig*, std::size_t>> distinct;
  std::vector<std::vector<std::size_t>> slot_of_eye(rigs.size());
  for (const Rig& rig : rigs)
    for (std::size_t eye = 0; eye < rig.T_base_cameras.size(); ++eye) {
      const auto same = std::find_if(distinct.begin(), distinct.end(), [&](const auto& d) {
        return same_eye(*d.first, d.second, rig, eye);
      });
      slot_of_eye[&rig - rigs.data()].push_back(static_cast<std::size_t>(same - distinct.begin()));
      if (same == distinct.end()) distinct.emplace_back(&rig, eye);
    }
  std::vector<View> views;
  for (const auto& [rig, eye] : distinct) {
    if (Cancelled(cancel)) return cancelled();
    views.push_back(Render(*rig, eye));
    views.back().band = TsdfVolume::BandBlocks(rig->volume, rig->camera, rig->T_base_cameras[eye], views.back().range);
  }
  spdlog::debug("expected surfaces: {} surfaces from {} distinct eyes", rigs.size(), distinct.size());
  for (std::size_t i = 0; i < options.size(); ++i) {
    if (!clouds[i].ok()) continue;
    if (Cancelled(cancel)) return cancelled();
    const std::size_t r = rig_of_options[i];
    std::vector<const View*> view_of_eye;
    for (std::size_t slot : slot_of_eye[r]) view_of_eye.push_back(&views[slot]);
    clouds[i] = SampleFused(options[i], Fuse(rigs[r], view_of_eye, cancel), nullptr, samples);
    if (clouds[i].status().code() == StatusCode::kCancelled) return cancelled();
  }
  return clouds;
}

Result<PointCloud> ExpectedRobotSurface(const TriangleMesh& robot_base, const ReconstructionOptions& options,
                                        std::size_t samples, std::uint64_t seed) {
  ARREF_RETURN_IF_ERROR(CheckOptions(options));
  ARREF_ASSIGN_OR_RETURN(const ExpectedSurfaceMaker maker, ExpectedSurfaceMaker::Create(robot_base, seed));
  return maker.Make(options, samples);
}

double MedianEdgeLength(const TriangleMesh& mesh) {
  if (mesh.empty()) return 0.0;
  // At most ~100,000 triangles, spread over the mesh: the median needs no more.
  const std::size_t stride = std::max<std::size_t>(1, mesh.triangles.size() / 100000);
  std::vector<float> edges(3 * ((mesh.triangles.size() + stride - 1) / stride));
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, edges.size() / 3, 4096), [&](const auto& r) {
    for (std::size_t k = r.begin(); k < r.end(); ++k) {
      const Triangle& tri = mesh.triangles[k * stride];
      for (int e = 0; e < 3; ++e) edges[3 * k + e] = (mesh.vertices[tri[e]] - mesh.vertices[tri[(e + 1) % 3]]).norm();
    }
  });
  return UpperMiddle(edges);
}

}  // namespace arref
