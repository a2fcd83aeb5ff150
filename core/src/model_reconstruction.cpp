#include "arref/model_reconstruction.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "arref/model_visibility.h"
#include "arref/nearest_neighbor.h"
#include "arref/raycaster.h"
#include "arref/sampling.h"
#include "arref/tsdf.h"

namespace arref {
namespace {

Status CheckOptions(const ReconstructionOptions& o) {
  if (!(o.voxel_m >= 0.002 && o.voxel_m <= 0.5))
    return Status::InvalidArgument(fmt::format("expected surface: voxel {} m is outside [0.002, 0.5] m", o.voxel_m));
  if (!(o.truncation_voxels >= 1)) return Status::InvalidArgument("expected surface: truncation must be >= 1 voxel");
  if (o.azimuths < 1 || !(o.pixels_per_voxel > 0) || !(o.distance_m > 0) || !(o.fov_horizontal_deg > 0 && o.fov_horizontal_deg < 170))
    return Status::InvalidArgument("expected surface: needs eye positions and an image size");
  return Status::Ok();
}

Result<TriangleMesh> FuseRobot(const TriangleMesh& robot_base, const ReconstructionOptions& o) {
  auto caster = RayCaster::Create(WithFloor(robot_base));
  if (!caster.ok()) return caster.status();
  const Aabb box = BoundsOf(robot_base.vertices);
  const Vec3 centre = ((box.min + box.max) / 2).cast<double>();
  TsdfOptions tsdf;
  tsdf.voxel_m = o.voxel_m;
  tsdf.truncation_m = std::max(o.truncation_voxels * o.voxel_m, o.min_truncation_m);
  tsdf.crop_center = centre;
  tsdf.crop_radius_m = 0.5 * (box.max - box.min).norm() + 2 * tsdf.truncation_m;
  TsdfVolume volume(tsdf);
  const double image_width_m = 2 * o.distance_m * std::tan(o.fov_horizontal_deg * std::numbers::pi / 360);
  const int width = std::clamp(static_cast<int>(std::ceil(image_width_m / o.voxel_m * o.pixels_per_voxel)), 64, 2048);
  const PinholeCamera camera = PinholeCamera::FromFov(width, width * 9 / 10, o.fov_horizontal_deg);
  const double max_range = o.distance_m + 2 * tsdf.crop_radius_m + o.eye_height_m;
  for (int a = 0; a < o.azimuths; ++a) {
    const double azimuth = 2 * std::numbers::pi * a / o.azimuths;
    const Iso3 T_base_camera =
        LookAt(Vec3(o.distance_m * std::cos(azimuth), o.distance_m * std::sin(azimuth), o.eye_height_m), centre);
    std::vector<float> incidence;
    const RangeImage range = caster->Render(camera, T_base_camera, max_range, &incidence);
    ARREF_RETURN_IF_ERROR(volume.Integrate(camera, T_base_camera, range, incidence));
  }
  return volume.ExtractMesh();
}

// The fused triangles that belong to the robot: nearer to its surface than to the floor.
TriangleMesh RobotPart(const TriangleMesh& fused, const TriangleMesh& robot_base, std::uint64_t seed) {
  const PointIndex robot(SampleSurface(robot_base, 20000, seed).points);
  const float floor_z = std::min(0.0f, BoundsOf(robot_base.vertices).min.z());
  TriangleMesh out;
  out.vertices = fused.vertices;
  for (const Triangle& t : fused.triangles) {
    const Vec3f c = (fused.vertices[t[0]] + fused.vertices[t[1]] + fused.vertices[t[2]]) / 3.0f;
    const float to_floor = c.z() - floor_z;
    std::uint32_t i;
    float sq;
    if (robot.NearestWithin(c, to_floor * to_floor, &i, &sq)) out.triangles.push_back(t);
  }
  return out;
}

}  // namespace

Result<PointCloud> ExpectedRobotSurface(const TriangleMesh& robot_base, const ReconstructionOptions& options,
                                        std::size_t samples, std::uint64_t seed) {
  ARREF_RETURN_IF_ERROR(CheckOptions(options));
  if (robot_base.empty()) return Status::InvalidArgument("expected surface: the robot has no geometry");
  auto fused = FuseRobot(robot_base, options);
  if (!fused.ok()) return fused.status().WithContext("expected surface");
  const TriangleMesh robot = RobotPart(*fused, robot_base, seed);
  if (robot.empty())
    return Status::FailedPrecondition(
        fmt::format("expected surface: nothing of the robot survives fusion at {} m voxels", options.voxel_m));
  return SampleSurface(robot, samples, seed);
}

double MedianEdgeLength(const TriangleMesh& mesh) {
  if (mesh.empty()) return 0.0;
  // At most ~100,000 triangles, spread over the mesh: the median needs no more.
  const std::size_t stride = std::max<std::size_t>(1, mesh.triangles.size() / 100000);
  std::vector<float> edges;
  for (std::size_t t = 0; t < mesh.triangles.size(); t += stride) {
    const Triangle& tri = mesh.triangles[t];
    for (int k = 0; k < 3; ++k) edges.push_back((mesh.vertices[tri[k]] - mesh.vertices[tri[(k + 1) % 3]]).norm());
  }
  auto mid = edges.begin() + static_cast<std::ptrdiff_t>(edges.size() / 2);
  std::nth_element(edges.begin(), mid, edges.end());
  return *mid;
}

}  // namespace arref
