// How far the headset's own errors move the robot in its mesh (private to arref_sim).
//
// A fused mesh puts each surface where the depth images said it was, seen from where head
// tracking believed the camera stood: a view's tracking error moves what it saw, and the fusion
// averages those moves over the views that saw each spot. Each spatial surface is then moved
// again by the head-pose error of the time it was meshed. A fit that explains the mesh perfectly
// still lands where those errors put the robot, so the bench measures that and keeps it apart
// from the method's own error.
#pragma once

#include <functional>
#include <optional>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/fusion/raycaster.h"

namespace arref::sim::detail {

class MeshImprint {
 public:
  // The robot's true surface samples (world, with normals) and its base (world).
  MeshImprint(PointCloud robot_world, const Vec3& base_world);

  // One depth image, taken from T_world_camera_true and fused at T_world_camera_believed. A
  // sample counts as seen when it faces the camera and the image's range at its pixel is within
  // `tolerance_m` of its distance (not hidden by another part, not dropped).
  void AddView(const PinholeCamera& camera, const Iso3& T_world_camera_true, const Iso3& T_world_camera_believed,
               const RangeImage& range, double tolerance_m);

  // The gravity-aligned rigid motion (x, y, z, yaw about the base; world: the true robot to where
  // the mesh put it) that best explains, point to plane as arref-icp fits, where the mesh put the
  // samples that were seen: moved along their normal by the mean of their views' moves, then by
  // `T_moved_true_at` (a surface's error at a world point; empty: none). None with too few seen.
  std::optional<Iso3> Motion(const std::function<Iso3(const Vec3&)>& T_moved_true_at = {}) const;
  // The ADD (mean over all samples) of such a motion: the mesh error; -1 without samples.
  double AddOf(const Iso3& T_mesh_true) const;

  std::size_t seen() const;

 private:
  PointCloud robot_;
  Vec3 base_;
  std::vector<double> moved_sum_;  // per sample: sum over its views of the move along its normal
  std::vector<int> views_;        // per sample: how many views saw it
};

}  // namespace arref::sim::detail
