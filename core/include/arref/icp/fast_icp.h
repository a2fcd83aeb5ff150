// arref's ICP kernel: point-to-plane or point-to-point Gauss-Newton on SE(3) (or its
// gravity-aligned 4-DoF subgroup) with a Geman-McClure kernel and normal-compatible
// correspondences, over plain point arrays. Correspondence search and reduction run in
// parallel (oneTBB).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "arref/base/cancel.h"
#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/scene/nearest_neighbor.h"

namespace arref {

// The scene side, built once per request: points, outward normals and their k-d tree.
class TargetCloud {
 public:
  explicit TargetCloud(PointCloud scene);  // needs normals
  const PointIndex& index() const { return index_; }
  const std::vector<Vec3f>& normals() const { return normals_; }
  std::size_t size() const { return index_.size(); }

 private:
  std::vector<Vec3f> normals_;
  PointIndex index_;
};

// What a pair's residual measures.
enum class IcpMetric {
  kPointToPlane,  // n . (T p - q), Chen & Medioni 1992: slides along surfaces; arref-icp's
  kPointToPoint,  // |T p - q|, Besl & McKay 1992: the paper's (and PCL's) ICP
};

struct IcpSettings {
  IcpMetric metric = IcpMetric::kPointToPlane;
  double max_correspondence_m = 0.05;
  int max_iterations = 30;
  // Geman-McClure scale (Black & Rangarajan 1996): weight = (s^2 / (s^2 + r^2))^2.
  double kernel_scale_m = 0.01;
  // Pairs whose normals differ by more than 60 degrees are no match (tested when the source
  // has normals; the target always has them).
  double min_normal_cos = 0.5;
  bool yaw_only = false;        // 4-DoF: x, y, z and yaw about gravity
  double converged_translation_m = 1e-4;  // a step this small ends the level
  double converged_rotation_rad = 1e-4;
  // So does a robust cost (mean over the source points) that changed by less than this fraction
  // since the last iteration: the termination of Besl & McKay 1992 (their tau, relative here).
  // Near the end a level can slide ~1 mm per iteration along a valley where the cost is flat;
  // those iterations bring no fit closer (docs/engine.md, "Refinement"). 0 turns it off.
  double converged_cost_ratio = 1e-3;
  // Polled before every iteration; once cancelled, the pose reached so far is returned with
  // IcpStats::cancelled set. Null: never cancelled (and the result is as without the field).
  const CancelToken* cancel = nullptr;
};

struct IcpStats {
  Iso3 T_target_source = Iso3::Identity();
  int iterations = 0;
  bool converged = false;
  std::size_t correspondences = 0;  // in the last iteration
  bool cancelled = false;  // IcpSettings::cancel stopped it: the pose is not a result
};

// Aligns source (points + normals, its own frame) to target, starting at T_target_source.
IcpStats Align(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
               const IcpSettings& settings);

// Runs Align once per correspondence distance, coarse to fine. weights: one per source point,
// multiplying its robust weight (as TrackingErrorWeights gives them); empty: all equal, else
// exactly one per source point (InvalidArgument otherwise). A cancel stops it within the running
// level and starts no further one: the result is then ok with IcpStats::cancelled set.
Result<IcpStats> AlignCoarseToFine(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
                           const std::vector<double>& distances_m, IcpSettings settings,
                           std::span<const float> weights = {});

struct AlignmentScore {
  double inlier_fraction = 0.0;  // source points with a normal-compatible target point within the threshold
  double rms_inliers_m = 0.0;
};
AlignmentScore ScoreAlignment(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
                              double inlier_threshold_m, double min_normal_cos);

// Median point-to-plane distance of the source points that have a normal-compatible target
// point within max_distance_m (infinity when none has): how closely a surface lies on the scene.
double MedianPlaneDistance(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
                           double max_distance_m, double min_normal_cos);

}  // namespace arref
