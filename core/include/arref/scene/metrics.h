// How good a pose is: against the scene (no ground truth needed) and against ground truth.
#pragma once

#include <vector>

#include "arref/base/geometry.h"
#include "arref/scene/nearest_neighbor.h"

namespace arref {

struct FitQuality {
  double rms_m = 0.0;            // the paper's metric: RMS over model points of the distance to the nearest scene point
  double inlier_fraction = 0.0;  // model points within the inlier threshold of the scene
  std::size_t model_points = 0;
};

FitQuality MeasureFit(const std::vector<Vec3f>& model_base, const Iso3& T_world_base, const PointIndex& scene_world,
                      double inlier_threshold_m);

struct PoseError {
  double translation_m = 0.0;  // |t_est - t_true|
  double vertical_m = 0.0;     // (t_est - t_true) along the world's z (gravity), signed
  double horizontal_m = 0.0;   // |t_est - t_true| in the world's xy plane
  double rotation_deg = 0.0;   // angle of R_true^T R_est
  double add_m = 0.0;          // ADD (Hinterstoisser et al. 2012): mean |T_est x - T_true x| over model points
};

PoseError ComparePoses(const Iso3& T_est, const Iso3& T_true, const std::vector<Vec3f>& model_points);

}  // namespace arref
