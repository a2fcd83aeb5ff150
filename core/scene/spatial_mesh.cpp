#include "arref/scene/spatial_mesh.h"

#include <tbb/parallel_for.h>

#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "arref/scene/nearest_neighbor.h"

namespace arref {
namespace {

std::string SurfaceName(const Surface& s) { return "surface " + std::to_string(s.id); }

bool IsFinite(const Iso3& T) { return T.matrix().allFinite(); }

double TriangleArea(const TriangleMesh& mesh, const Triangle& t) {
  const Vec3f a = mesh.vertices[t[0]];
  return 0.5 * static_cast<double>((mesh.vertices[t[1]] - a).cross(mesh.vertices[t[2]] - a).norm());
}

}  // namespace

Status ValidateSurface(const Surface& surface) {
  const TriangleMesh& mesh = surface.mesh;
  if (mesh.vertices.empty() || mesh.triangles.empty())
    return Status::InvalidArgument(SurfaceName(surface) + " is empty (" + std::to_string(mesh.vertices.size()) +
                                   " vertices, " + std::to_string(mesh.triangles.size()) + " triangles)");
  if (!IsFinite(surface.T_world_surface))
    return Status::InvalidArgument(SurfaceName(surface) + ": transform to world is not finite");
  const Eigen::Matrix3d R = surface.T_world_surface.linear();
  if (!(R.transpose() * R).isApprox(Eigen::Matrix3d::Identity(), 1e-4) || R.determinant() < 0)
    return Status::InvalidArgument(SurfaceName(surface) + ": transform to world is not a rigid rotation");
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    if (!mesh.vertices[i].allFinite())
      return Status::InvalidArgument(SurfaceName(surface) + ": vertex " + std::to_string(i) + " is not finite");
  const auto n = mesh.vertices.size();
  std::size_t degenerate = 0;
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    const Triangle& t = mesh.triangles[i];
    for (auto index : t)
      if (index >= n)
        return Status::InvalidArgument(SurfaceName(surface) + ": triangle " + std::to_string(i) + " uses vertex " +
                                       std::to_string(index) + " but there are only " + std::to_string(n));
    if (TriangleArea(mesh, t) <= 1e-12) ++degenerate;
  }
  if (degenerate == mesh.triangles.size())
    return Status::InvalidArgument(SurfaceName(surface) + ": all " + std::to_string(degenerate) +
                                   " triangles are degenerate (zero area)");
  return Status::Ok();
}

Status SpatialMesh::Upsert(Surface surface) {
  ARREF_RETURN_IF_ERROR(ValidateSurface(surface));
  surfaces_[surface.id] = std::move(surface);
  merged_.reset();
  return Status::Ok();
}

bool SpatialMesh::Remove(std::uint64_t id) {
  if (surfaces_.erase(id) == 0) return false;
  merged_.reset();
  return true;
}

std::size_t SpatialMesh::vertex_count() const {
  std::size_t n = 0;
  for (const auto& [id, s] : surfaces_) n += s.mesh.vertices.size();
  return n;
}

std::shared_ptr<const TriangleMesh> SpatialMesh::MergedWorld() const {
  if (merged_) return merged_;
  auto merged = std::make_shared<TriangleMesh>();
  std::size_t vertices = 0, triangles = 0;
  for (const auto& [id, s] : surfaces_) vertices += s.mesh.vertices.size(), triangles += s.mesh.triangles.size();
  merged->vertices.reserve(vertices), merged->triangles.reserve(triangles);
  for (const auto& [id, s] : surfaces_) merged->Append(s.mesh, s.T_world_surface);
  merged_ = std::move(merged);
  return merged_;
}

TriangleMesh CropToSphere(const TriangleMesh& mesh, const Vec3& center, double radius) {
  const Vec3f c = center.cast<float>();
  const float r2 = static_cast<float>(radius * radius);
  std::vector<std::int64_t> remap(mesh.vertices.size(), -1);
  TriangleMesh out;
  auto keep = [&](std::uint32_t v) {
    if (remap[v] < 0) {
      remap[v] = static_cast<std::int64_t>(out.vertices.size());
      out.vertices.push_back(mesh.vertices[v]);
    }
    return static_cast<std::uint32_t>(remap[v]);
  };
  for (const auto& t : mesh.triangles) {
    const bool inside = (mesh.vertices[t[0]] - c).squaredNorm() <= r2 || (mesh.vertices[t[1]] - c).squaredNorm() <= r2 ||
                        (mesh.vertices[t[2]] - c).squaredNorm() <= r2;
    if (inside) out.triangles.push_back({keep(t[0]), keep(t[1]), keep(t[2])});
  }
  return out;
}

TriangleMesh KeepTriangles(const TriangleMesh& mesh, const std::function<bool(const Triangle&)>& keep) {
  std::vector<char> kept(mesh.triangles.size());
  tbb::parallel_for(std::size_t{0}, kept.size(), [&](std::size_t i) { kept[i] = keep(mesh.triangles[i]); });
  TriangleMesh out;
  out.vertices = mesh.vertices;
  for (std::size_t i = 0; i < kept.size(); ++i)
    if (kept[i]) out.triangles.push_back(mesh.triangles[i]);
  return out;
}

TriangleMesh TrianglesNear(const TriangleMesh& mesh, const PointIndex& points, double distance_m) {
  // Without points the box is empty (BoundsOf) and no triangle is kept.
  const Aabb near = BoundsOf(points.points()).Grown(static_cast<float>(distance_m));
  const float limit_sq = static_cast<float>(distance_m * distance_m);
  return KeepTriangles(mesh, [&](const Triangle& t) {
    const Vec3f c = Centroid(mesh, t);
    return near.Contains(c) && points.AnyWithin(c, limit_sq);
  });
}

std::vector<Surface> SplitIntoSurfaces(const TriangleMesh& world, double chunk_m, double timestamp_s) {
  using ChunkKey = std::array<int, 3>;
  std::map<ChunkKey, std::vector<std::uint32_t>> chunks;
  for (std::uint32_t t = 0; t < world.triangles.size(); ++t) {
    const Triangle& tri = world.triangles[t];
    const Vec3f c = (world.vertices[tri[0]] + world.vertices[tri[1]] + world.vertices[tri[2]]) / 3.0f;
    ChunkKey key;
    for (int a = 0; a < 3; ++a) key[a] = static_cast<int>(std::floor(c[a] / chunk_m));
    chunks[key].push_back(t);
  }
  std::vector<Surface> surfaces;
  // local[v]: v's index in the surface being built, valid where stamp[v] is that surface's id.
  std::vector<std::uint32_t> local(world.vertices.size());
  std::vector<std::uint64_t> stamp(world.vertices.size(), 0);
  for (const auto& [key, tris] : chunks) {
    Surface s;
    s.id = surfaces.size() + 1;
    s.timestamp_s = timestamp_s;
    // The corner in double, then float: the same vertices as the simulator's cells have always had.
    const Vec3 corner = Vec3(key[0], key[1], key[2]) * chunk_m;
    s.T_world_surface = Iso3(Eigen::Translation3d(corner));
    const Vec3f corner_f = corner.cast<float>();
    for (std::uint32_t t : tris) {
      Triangle out;
      for (int k = 0; k < 3; ++k) {
        const std::uint32_t v = world.triangles[t][k];
        if (stamp[v] != s.id) {
          stamp[v] = s.id;
          local[v] = static_cast<std::uint32_t>(s.mesh.vertices.size());
          s.mesh.vertices.push_back(world.vertices[v] - corner_f);
        }
        out[k] = local[v];
      }
      s.mesh.triangles.push_back(out);
    }
    surfaces.push_back(std::move(s));
  }
  return surfaces;
}

}  // namespace arref
