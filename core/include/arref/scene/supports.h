// Horizontal supports in a gravity-aligned scene: the heights of the floor, pedestal and table
// tops an upright robot's base can rest on. A seed's height says little (users put the cube on
// the floor at the foot of a pedestal, or at the robot's waist); the support under the robot
// says where its base is.
#pragma once

#include <vector>

#include "arref/base/geometry.h"

namespace arref {

struct SupportSearch {
  Vec3 centre = Vec3::Zero();  // world; only points within `radius_m` of its vertical axis count
  double radius_m = 1.0;
  double min_up_cos = 0.94;    // a support faces up within about 20 degrees
  double bin_m = 0.02;         // height histogram bin (about the mesh's noise)
  double min_share = 0.02;     // a support holds at least this share of the up-facing points
  std::size_t max_supports = 4;
};

struct Support {
  double z = 0.0;            // world height of the surface
  std::size_t points = 0;    // up-facing scene points on it
};

// Peaks of the height histogram of up-facing points (scene needs normals), most points first.
std::vector<Support> FindSupports(const PointCloud& scene_world, const SupportSearch& search);

}  // namespace arref
