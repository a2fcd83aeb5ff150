// How far a gravity-aligned fit of the robot to a headset's mesh may be off, as a covariance of
// (x, y, z, yaw) with three parts:
// - the fit's: what its own point-to-plane residuals imply (how precisely this mesh pins it);
// - the map's: how far the headset's tracking error while it mapped moves the robot's surface in
//   the mesh, propagated from a stated error per view (TrackingError) and the eyes the surface
//   was seen from. No residual can show this part: the whole surface moves together;
// - the surface model's: when two models of the robot's surface were fitted (arref-icp's
//   predicted shell and its exact surface) and one kept, how far apart their fits lie. Neither
//   is known to be right on a mesh made by another mesher, so the pose is taken to lie at either
//   by its chance: a covariance of q (1 - q) delta delta^T for the poses' difference delta. And
//   how far the kept model lies off the mesh: a shell that differs from the mesh by a systematic
//   m (median plane distance) can hold the fit off by about m, which no residual count averages
//   away, so m counts as a horizontal error of m (the wearer looks at the arm from the side).
#pragma once

#include <cmath>
#include <cstddef>
#include <span>

#include "arref/base/geometry.h"
#include "arref/fusion/tracking_error.h"
#include "arref/icp/fast_icp.h"
#include "arref/icp/registration_output.h"

namespace arref {

struct PrecisionSettings {
  double max_distance_m = 0.02;  // model points farther from the scene than this are no pair
  double min_normal_cos = 0.5;
  // Residuals of points closer than this are not independent: a mesh errs by whole facets, so
  // the count of pairs is taken as the count of cells of this side they fall in. The mesh's
  // voxel (or its edge length); 0: every pair counts.
  double correlation_m = 0.0;
  // The error of each view's head pose; the map's part needs eyes too.
  TrackingError view_error;
};

struct FitPrecision {
  bool valid = false;  // at least 5 pairs and a solvable system
  // Of (x, y, z, yaw), the yaw about the base's vertical axis; world frame, metres and radians.
  Eigen::Matrix4d fit_covariance = Eigen::Matrix4d::Zero();
  Eigen::Matrix4d map_covariance = Eigen::Matrix4d::Zero();      // zero without eyes
  Eigen::Matrix4d surface_covariance = Eigen::Matrix4d::Zero();  // zero with one surface model
  Eigen::Matrix4d covariance() const { return fit_covariance + map_covariance + surface_covariance; }
  double sigma_horizontal_m() const { return std::sqrt(covariance()(0, 0) + covariance()(1, 1)); }
  double sigma_vertical_m() const { return std::sqrt(covariance()(2, 2)); }
  double sigma_yaw_rad() const { return std::sqrt(covariance()(3, 3)); }
  // The root mean square displacement of the model's points under covariance(): roughly the ADD
  // (mean point error) of one standard deviation of the pose's error.
  double expected_error_m = 0.0;
  double fit_error_m = 0.0;  // the same of each part alone
  double map_error_m = 0.0;
  double surface_error_m = 0.0;
  // The kept surface model's misfit (OtherSurfaceFit::kept_misfit_m), part of surface_error_m;
  // 0 with one model. What a status reason names when the mesh is not what the model expected.
  double surface_misfit_m = 0.0;
  double residual_rms_m = 0.0;
  std::size_t pairs = 0;
  std::size_t independent_pairs = 0;  // pairs counted by correlation cells
};

// Point-to-plane pairs of the model's points posed at T_world_base with the scene, their
// Jacobians J in (x, y, z, yaw) (Low 2004, eq. 8, restricted to gravity-aligned motion about the
// base's axis) and H = J^T J.
// - The fit's part: sigma^2 H^-1 at the optimum (the Gauss-Newton estimate, e.g. Censi 2007),
//   scaled by pairs / independent pairs.
// - The map's part: a view k whose head pose errs by (t_k, w_k) moves a surface point p it sees
//   by t_k + w_k x (p - eye_k). A fused point moves by the mean over the eyes facing it, and the
//   least-squares fit follows that field: delta = H^-1 J^T (n . dp). Summed over independent
//   views, Cov = sum_k B_k S B_k^T with S = diag(position^2 I, orientation^2 I).
// - The surface model's part: the pose at the kept fit with chance 1 - q, at the other surface
//   model's fit with chance q, about their mean: q (1 - q) delta delta^T, delta their difference
//   in (x, y, z, yaw); plus diag(m^2 / 2, m^2 / 2, 0, 0) for the kept model's misfit m.
// eyes_world: where the surface was seen from; empty: no map part. other_surface: the other
// surface model's fit; null: no surface part.
FitPrecision MeasurePrecision(std::span<const Vec3f> model_base, std::span<const Vec3f> model_normals_base,
                              const TargetCloud& scene, const Iso3& T_world_base, std::span<const Vec3> eyes_world,
                              const OtherSurfaceFit* other_surface, const PrecisionSettings& settings);

}  // namespace arref
