// Open3D 0.16 (Debian's libopen3d-dev) as the simulator's second mesher: see open3d_mesher.h.
#include "open3d_mesher.h"

#include <open3d/camera/PinholeCameraIntrinsic.h>
#include <open3d/geometry/Image.h>
#include <open3d/geometry/RGBDImage.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/pipelines/integration/ScalableTSDFVolume.h>
#include <open3d/utility/Logging.h>

#include <cstring>
#include <limits>
#include <string>

namespace arref::sim {
namespace {

TriangleMesh FromOpen3d(const open3d::geometry::TriangleMesh& in) {
  TriangleMesh out;
  out.vertices.reserve(in.vertices_.size());
  for (const auto& v : in.vertices_) out.vertices.push_back(v.cast<float>());
  out.triangles.reserve(in.triangles_.size());
  for (const auto& t : in.triangles_)
    out.triangles.push_back({static_cast<std::uint32_t>(t[0]), static_cast<std::uint32_t>(t[1]), static_cast<std::uint32_t>(t[2])});
  return out;
}

open3d::geometry::TriangleMesh ToOpen3d(const TriangleMesh& in) {
  open3d::geometry::TriangleMesh out;
  out.vertices_.reserve(in.vertices.size());
  for (const auto& v : in.vertices) out.vertices_.push_back(v.cast<double>());
  out.triangles_.reserve(in.triangles.size());
  for (const auto& t : in.triangles)
    out.triangles_.emplace_back(static_cast<int>(t[0]), static_cast<int>(t[1]), static_cast<int>(t[2]));
  return out;
}

// Open3D integrates z-depth in metres (float) and centres pixel u on the integer u; the range
// images hold distances along the ray through the centre of [u, u+1).
open3d::geometry::Image DepthImage(const PinholeCamera& camera, const RangeImage& range, double max_range_m) {
  open3d::geometry::Image depth;
  depth.Prepare(camera.width, camera.height, 1, 4);
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(u);
      const float r = range[i];
      const float z = (r > 0 && r <= max_range_m) ? static_cast<float>(r * camera.RayDirection(u, v).z()) : 0.0f;
      std::memcpy(depth.data_.data() + 4 * i, &z, sizeof z);
    }
  return depth;
}

}  // namespace

bool Open3dAvailable() { return true; }

Result<std::vector<TriangleMesh>> FuseWithOpen3d(const PinholeCamera& camera, const std::vector<Iso3>& T_world_camera,
                                                 const std::vector<RangeImage>& ranges, const Open3dFusion& options,
                                                 const std::vector<int>& snapshot_after) {
  if (T_world_camera.size() != ranges.size()) return Status::InvalidArgument("Open3D fusion: one pose per range image");
  open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
  namespace integration = open3d::pipelines::integration;
  integration::ScalableTSDFVolume volume(options.voxel_m, options.truncation_m, integration::TSDFVolumeColorType::NoColor);
  const open3d::camera::PinholeCameraIntrinsic intrinsic(camera.width, camera.height, camera.focal_px, camera.focal_px,
                                                         camera.cx() - 0.5, camera.cy() - 0.5);
  std::vector<TriangleMesh> meshes;
  std::size_t next = 0;
  for (int i = 0; i < static_cast<int>(ranges.size()); ++i) {
    if (ranges[static_cast<std::size_t>(i)].size() != static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height))
      return Status::InvalidArgument("Open3D fusion: range image " + std::to_string(i) + " has the wrong size");
    open3d::geometry::RGBDImage rgbd;
    rgbd.depth_ = DepthImage(camera, ranges[static_cast<std::size_t>(i)], options.max_range_m);
    rgbd.color_ = rgbd.depth_;  // not read: the volume keeps no colour
    volume.Integrate(rgbd, intrinsic, T_world_camera[static_cast<std::size_t>(i)].inverse().matrix());
    for (; next < snapshot_after.size() && snapshot_after[next] <= i; ++next)
      meshes.push_back(FromOpen3d(*volume.ExtractTriangleMesh()));
  }
  for (; next < snapshot_after.size(); ++next) meshes.push_back(FromOpen3d(*volume.ExtractTriangleMesh()));
  return meshes;
}

Result<TriangleMesh> DecimateWithOpen3d(const TriangleMesh& mesh, int target_triangles) {
  if (target_triangles < 1) return Status::InvalidArgument("decimation target must be >= 1 triangle");
  if (static_cast<int>(mesh.triangles.size()) <= target_triangles) return mesh;
  open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
  const auto simplified = ToOpen3d(mesh).SimplifyQuadricDecimation(target_triangles, std::numeric_limits<double>::infinity(), 1.0);
  simplified->RemoveDegenerateTriangles();
  simplified->RemoveUnreferencedVertices();
  return FromOpen3d(*simplified);
}

}  // namespace arref::sim
