// Which parts of a robot a person walking around it can see.
//
// A third to half of a robot is never seen by the headset, and surfaces that no one can see
// at all (faces against the floor, undersides, surfaces enclosed by other links) drag ICP
// 2-3 cm off when they are fitted (docs/engine.md, "The problem"). They are found
// here once per robot and joint state, by rendering the posed robot from eye positions.
#pragma once

#include <algorithm>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref {

struct VisibilityOptions {
  int azimuths = 16;                           // eye positions around the robot
  std::vector<double> distances_m = {1.5, 2.5};  // from the robot base, horizontally
  std::vector<double> eye_heights_m = {1.2, 1.9};  // above the base's z = 0
  int image_width = 200;
  int image_height = 160;
  double fov_horizontal_deg = 90.0;
  double depth_tolerance_m = 0.02;
  bool floor = true;  // a floor at z = 0 of the base hides the faces standing on it
};

// The height of the floor a robot model stands on (its base frame): z = 0, or its lowest point
// when something of it hangs below that (robot_box: the model's bounds).
inline float FloorHeight(const Aabb& robot_box) { return std::min(0.0f, robot_box.min.z()); }

// The robot standing on a floor: a 20 m square at FloorHeight, which hides the faces standing
// on it.
TriangleMesh WithFloor(const TriangleMesh& robot_base);

// Per sample point: the fraction of eye positions that see it (unoccluded, facing the eye).
// Needs normals on the samples (outward, as from SampleSurface).
// The points with visibility > 0, with their attributes. The whole cloud when it carries no
// visibility, or when fewer than 50 points would remain (too few to fit or to measure).
PointCloud VisiblePoints(const PointCloud& model);

Result<std::vector<float>> ModelVisibility(const TriangleMesh& robot_base, const PointCloud& samples,
                                           const VisibilityOptions& options = {});

}  // namespace arref
