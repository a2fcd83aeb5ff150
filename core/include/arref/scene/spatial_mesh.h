// The headset's spatial map: surfaces with ids, each with its own transform to world.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref {

class PointIndex;

struct Surface {
  std::uint64_t id = 0;
  TriangleMesh mesh;                     // vertices in the surface's own frame (internal convention)
  Iso3 T_world_surface = Iso3::Identity();
  double timestamp_s = 0.0;
};

// Rejects non-finite vertices or transform, indices out of range, empty surfaces and
// surfaces whose triangles are all degenerate. The message names the surface and element.
Status ValidateSurface(const Surface& surface);

// Latest version of each surface, by id (an update replaces the old one, as on a HoloLens).
class SpatialMesh {
 public:
  Status Upsert(Surface surface);  // validated first; a bad surface leaves the map unchanged
  bool Remove(std::uint64_t id);
  std::size_t size() const { return surfaces_.size(); }
  std::size_t vertex_count() const;
  const std::map<std::uint64_t, Surface>& surfaces() const { return surfaces_; }
  // All surfaces in world coordinates, as one mesh: merged once per change of the map and
  // shared, so that a session's requests on an unchanged map neither copy it nor hold a copy
  // each (the merge was about a twentieth of a request's CPU).
  std::shared_ptr<const TriangleMesh> MergedWorld() const;

 private:
  std::map<std::uint64_t, Surface> surfaces_;
  mutable std::shared_ptr<const TriangleMesh> merged_;  // reset by every change
};

// Keeps triangles with at least one vertex within radius of center (drops unused vertices).
TriangleMesh CropToSphere(const TriangleMesh& mesh, const Vec3& center, double radius);

// The triangles that `keep` accepts, on the same vertices and in the same order. `keep` is
// called from several threads at once (the per-request tests are nearest-neighbour queries).
TriangleMesh KeepTriangles(const TriangleMesh& mesh, const std::function<bool(const Triangle&)>& keep);

// Keeps the triangles whose centroid lies within distance_m of one of the points (the same
// vertices, unused ones included): the part of a mesh round a fitted model.
TriangleMesh TrianglesNear(const TriangleMesh& mesh, const PointIndex& points, double distance_m);

// Splits a world mesh into surfaces like the spatial mapper's: one per chunk_m cube of a world
// grid (the cube of a triangle's centroid), ids 1, 2, ... in grid order, each surface's vertices
// relative to its cube's corner and stamped timestamp_s.
std::vector<Surface> SplitIntoSurfaces(const TriangleMesh& world, double chunk_m, double timestamp_s);

}  // namespace arref
