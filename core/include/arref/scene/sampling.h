// Surface sampling and point-cloud resampling.
#pragma once

#include <cstdint>

#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref {

// n points uniform by area over the mesh surface, with the face normal of each point's
// triangle. Deterministic for a given seed. Empty mesh or n == 0 gives an empty cloud.
PointCloud SampleSurface(const TriangleMesh& mesh, std::size_t n, std::uint64_t seed);

// The same points reordered cell by cell (cells of cell_m, z-major), so that consecutive points
// lie close together. Nearest-neighbour queries in that order reuse the k-d tree nodes in cache:
// an ICP iteration over 5,000 points runs about 10 % faster (bench/icp_benchmark.cpp).
PointCloud SpatiallyOrdered(const PointCloud& cloud, double cell_m = 0.1);

// Every k-th point so that at most `limit` remain (deterministic, spread over the cloud), spatially
// ordered; limit 0 keeps every point in its order.
PointCloud Thinned(const PointCloud& cloud, std::size_t limit);

// The cell of side cell_m that holds p, packed into one key (21 bits per axis: cells within
// 2^20 of the origin along each axis, a 2 km cube at 1 mm cells).
std::uint64_t CellKey(const Vec3f& p, double cell_m);

// One point per occupied voxel (the centroid of its points; normals averaged).
PointCloud VoxelDownsample(const PointCloud& cloud, double leaf_m);

}  // namespace arref
