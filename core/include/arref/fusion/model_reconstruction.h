// The robot as the headset's spatial mapper would mesh it.
//
// A headset mesh is not the robot's surface: depth fusion at a few centimetres per voxel
// rounds edges, fattens thin links and closes the space under overhangs. Fitting the exact
// model into that shell leaves a systematic error of the order of the voxel (7-10 mm on the
// simulated cells, mostly vertical, even without depth noise; docs/engine.md). Fitting instead
// the model passed through the same kind of fusion compares like with like, as in
// analysis-by-synthesis tracking: render what the sensor would see, compare that.
// Built once per robot, joint state and voxel size.
#pragma once

#include <array>
#include <compare>
#include <cstdint>
#include <memory>
#include <vector>

#include "arref/base/cancel.h"
#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref {

class RayCaster;
class PointIndex;
struct TsdfOptions;
class TsdfVolume;

struct ReconstructionOptions {
  double voxel_m = 0.035;         // the headset mesh's voxel (its median edge length)
  double truncation_voxels = 3.0;
  double min_truncation_m = 0.05;  // >= 6 sigma of the HoloLens' ~8 mm depth noise
  // Eyes on an arc of a circle round the robot, centred on arc_center_deg from the base's +x
  // (counter-clockwise); 360: all round. A user who mapped one side of the robot walked an arc.
  int azimuths = 24;
  double arc_deg = 360.0;
  double arc_center_deg = 0.0;
  double distance_m = 1.9;        // from the base, horizontally
  double eye_height_m = 1.65;     // above the base's z = 0
  // Images as fine as the voxels need: a pixel covers 1 / pixels_per_voxel of a voxel at the
  // robot's distance (finer costs time and changes nothing: the TSDF averages within a voxel).
  double pixels_per_voxel = 2.0;
  double fov_horizontal_deg = 75.0;
  // The eyes where the headset really was (base frame), when known: they replace the arc
  // (azimuths, arc_deg, arc_center_deg, distance_m, eye_height_m). Each looks at the robot.
  // Arrays, not Vec3: caches order options field by field, and Eigen vectors have no order.
  std::vector<std::array<double, 3>> eyes_base;
  auto operator<=>(const ReconstructionOptions&) const = default;  // field by field (caches key on it)
};

// Where options put the eyes (base frame): eyes_base when given, else on the arc.
std::vector<Vec3> EyePositions(const ReconstructionOptions& options);

// Makes expected surfaces of one posed robot: the ray caster of the robot on its floor and the
// index of its exact surface are built once and shared by every voxel size and walk.
class ExpectedSurfaceMaker {
 public:
  static Result<ExpectedSurfaceMaker> Create(const TriangleMesh& robot_base, std::uint64_t seed);
  ExpectedSurfaceMaker(ExpectedSurfaceMaker&&) noexcept;
  ExpectedSurfaceMaker& operator=(ExpectedSurfaceMaker&&) noexcept;
  ~ExpectedSurfaceMaker();
  // As ExpectedRobotSurface. Const and thread-safe.
  Result<PointCloud> Make(const ReconstructionOptions& options, std::size_t samples) const;
  // One surface per options, each as Make gives it. An eye that several of them share (walks
  // whose azimuths lie on one lattice) is rendered once: renders are half a surface's cost.
  // cancel is polled between renders and fusions (and inside each fusion): once cancelled, every
  // surface not yet made is Status::Cancelled.
  std::vector<Result<PointCloud>> MakeMany(const std::vector<ReconstructionOptions>& options,
                                           std::size_t samples, const CancelToken* cancel = nullptr) const;
  // The same with the other objects the headset mapped round the robot (a table, walls,
  // clutter): they hide parts of the robot from the eyes and fuse with it, as they did in the
  // headset's mesh. They are the triangles of scene_world, with the robot at T_world_base,
  // farther than clearance_m from the robot's exact surface.
  // cancel as MakeMany's, also between the images rendered with the objects.
  Result<PointCloud> MakeInContext(const ReconstructionOptions& options, std::size_t samples,
                                   const TriangleMesh& scene_world, const Iso3& T_world_base,
                                   double clearance_m, const CancelToken* cancel = nullptr) const;

 private:
  struct Parts;
  struct View;
  struct Rig;
  explicit ExpectedSurfaceMaker(std::unique_ptr<Parts> parts);
  Rig Eyes(const ReconstructionOptions& options) const;
  View Render(const Rig& rig, std::size_t eye) const;
  Result<TriangleMesh> Fuse(const Rig& rig, const std::vector<const View*>& robot_views,
                            const CancelToken* cancel) const;
  Result<TriangleMesh> FuseInContext(const Rig& rig, const RayCaster& scene, const CancelToken* cancel) const;
  std::vector<View> ViewsInContext(const Rig& rig, const RayCaster& scene, const TsdfVolume& volume,
                                   const CancelToken* cancel) const;
  TsdfOptions Volume(const ReconstructionOptions& options) const;
  Aabb Band(const ReconstructionOptions& options) const;
  TriangleMesh Context(const TriangleMesh& scene_world, const Iso3& T_world_base, double clearance_m) const;
  std::vector<Vec3f> FusedPart(const TriangleMesh& context_base, const ReconstructionOptions& options) const;
  TriangleMesh RobotPart(const TriangleMesh& fused, const PointIndex* context) const;
  // The robot fused with the objects (scene holds both) and split from them (context).
  Result<PointCloud> Sample(const ReconstructionOptions& options, const RayCaster& scene,
                            const PointIndex* context, std::size_t samples, const CancelToken* cancel) const;
  Result<PointCloud> SampleFused(const ReconstructionOptions& options, Result<TriangleMesh> fused,
                                 const PointIndex* context, std::size_t samples) const;
  std::unique_ptr<Parts> parts_;
};

// The fused robot's surface in its base frame, sampled (`samples` points with outward normals),
// with the floor it stands on cut away. Fails when the options make no sense or nothing
// of the robot is observed.
Result<PointCloud> ExpectedRobotSurface(const TriangleMesh& robot_base, const ReconstructionOptions& options,
                                        std::size_t samples, std::uint64_t seed);

// The voxel size of a surface-nets mesh (or a mapper's mesh of a given triangle density):
// the median edge length. 0 for a mesh without triangles.
double MedianEdgeLength(const TriangleMesh& mesh);

}  // namespace arref
