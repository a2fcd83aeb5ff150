// A second, independent way to mesh simulated depth: Open3D 0.16's scalable TSDF (Curless and
// Levoy 1996, as in KinectFusion, Newcombe et al. 2011) with marching cubes (Lorensen and Cline
// 1987) and quadric decimation (Garland and Heckbert 1997). It shares no code with core's own
// TSDF and surface nets, which arref-icp also uses to predict the headset's mesh: a benchmark
// on meshes made only by the product's own fusion would flatter it. Open3D's headers stay in
// open3d_mesher.cpp (they are slow to compile); without Open3D the functions say so.
#pragma once

#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/fusion/raycaster.h"

namespace arref::sim {

// Whether arref_sim was built with Open3D (libopen3d-dev).
bool Open3dAvailable();

struct Open3dFusion {
  double voxel_m = 0.03;
  double truncation_m = 0.09;
  double max_range_m = 4.0;
};

// Fuses range images (along each ray, as RayCaster::Render gives them) taken from
// T_world_camera[i] (optical frame) in order, and extracts a marching-cubes mesh in world
// after view snapshot_after[k] for every k (ascending): a surface updated at that time.
Result<std::vector<TriangleMesh>> FuseWithOpen3d(const PinholeCamera& camera, const std::vector<Iso3>& T_world_camera,
                                                 const std::vector<RangeImage>& ranges, const Open3dFusion& options,
                                                 const std::vector<int>& snapshot_after);

// Quadric edge-collapse decimation down to at most target_triangles (borders weighted so
// that a surface's outline stays where it is).
Result<TriangleMesh> DecimateWithOpen3d(const TriangleMesh& mesh, int target_triangles);

}  // namespace arref::sim
