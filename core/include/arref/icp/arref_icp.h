// arref-icp, the product's registration method: a gravity-aligned 4-DoF search around the
// seed (every yaw, a few heights, a position grid when needed), point-to-plane ICP of the
// robot as the headset would mesh it (or of the model points a person can see), and an
// ambiguity margin between the best distinct poses.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "arref/base/cancel.h"
#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/fusion/tracking_error.h"
#include "arref/icp/fast_icp.h"
#include "arref/icp/registration_output.h"

namespace arref {

class RobotSide;  // fusion/robot_side.h

struct ArrefIcpParams {
  int yaw_hypotheses = 12;
  // The seed's error the search covers, horizontally and in height: a user's cube lies within
  // this of the base (on the floor at a pedestal's foot, at the robot's waist, ...).
  double seed_error_m = 0.5;
  // Base heights from the horizontal supports near the seed (scene/supports.h), when any lies
  // within seed_error_m + support_margin_m of the seed's height; else these offsets from it.
  bool support_search = true;
  double support_margin_m = 0.1;
  bool rest_on_support = true;     // a fit within a voxel of a support's height is set on it
  std::vector<double> height_offsets_m = {-0.15};
  // The seed's horizontal error the yaw search captures without widening: a user's cube lies
  // 0.1-0.3 m from the base. The capture level reaches this far, or farther on a robot whose
  // outer points move more between two yaw hypotheses (SearchLengths, arref_icp.cpp).
  double placement_error_m = 0.3;
  double position_step_m = 0.0;    // the expanded search's grid step; 0: the capture level's reach
  int position_steps = 1;          // grid of (2 * steps + 1)^2 positions, within seed_error_m
  double expand_below_score = 0.35;  // widen the search when the best coarse score is lower
  double widen_below_refined_score = 0.3;  // ... or the best refined pose's (inliers at 2 cm)
  std::size_t coarse_points = 250;
  // The refinement's 8 and 4 cm levels (arref_icp.cpp): fewer points lose accuracy (docs/engine.md).
  std::size_t approach_points = 2000;
  std::size_t fine_points = 2000;
  // The last polish, on the surface refitted in context: more points average the mesh's bends.
  std::size_t context_points = 5000;
  // ... against the scene sampled afresh round the fitted robot, this many samples per voxel
  // face: with one sample per facet or fewer the nearest one often lies on a neighbouring
  // facet and tilts the residual's plane. 0: polish on the request's own scene samples.
  double context_target_density = 4.0;
  // The last polish weighs each point by the variance this error leaves along its normal, seen
  // from the refit's eyes (tracking_error.h). position_m 0: equal weights.
  TrackingError tracking_error;
  int refine_top = 2;
  int settle_top = 8;  // the yaw search's starts settled (the best once captured); the wide search settles all
  bool final_six_dof = false;      // a last 6-DoF step would absorb tilt of the headset world (robots stand upright)
  // Fit the robot as the headset would mesh it (model_reconstruction.h) rather than its exact
  // surface, when the caller supplies it.
  bool expected_surface = true;
  double expected_voxel_m = 0.0;   // the headset mesh's voxel; 0: the cropped scene's median edge length
  bool select_walk = true;         // also try surfaces of one-sided walks round the robot
  bool in_context = true;          // refit with the objects mapped round the robot fused in
  // Every ICP of the method: point-to-plane, or point-to-point for comparison (arref-icp-point).
  IcpMetric metric = IcpMetric::kPointToPlane;
};

// What arref-icp registers: the model in its base frame, the scene in world with its k-d tree.
struct ArrefIcpInput {
  const PointCloud& model_base;
  const PointCloud& scene_world;
  const TargetCloud& scene_target;  // scene_world's k-d tree
  const Iso3& T_world_seed;
  const ArrefIcpParams& params;
  // Optional. The robot's model side (for one-sided walks and the refit), the robot as the
  // headset would mesh it at this scene's voxel (walked all round), and the cropped headset
  // mesh the scene was sampled from (for the refit in context).
  const RobotSide* robot = nullptr;
  std::shared_ptr<const PointCloud> model_expected;
  double voxel_m = 0.0;
  const TriangleMesh* scene_mesh_world = nullptr;
  // Where the headset was while it mapped (world frame); empty: unknown.
  std::span<const Vec3> head_path_world;
  std::uint64_t sample_seed = 1;
  const CancelToken* cancel = nullptr;
};

Result<RegistrationOutput> RegisterArrefIcp(const ArrefIcpInput& in);

}  // namespace arref
