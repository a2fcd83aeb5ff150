// How much a headset's tracking error moves each point of a fused surface, as fitting weights.
//
// A spatial mesh fuses many views, each placed by the headset's head tracking with a small
// error of its own. An orientation error w about the eye moves a point at distance r by
// r |w| sideways, which at ~2 m dwarfs the position error: 0.3 degrees is 10 mm, against 4 mm.
// Seen head-on that sideways move slides along the surface and changes no point-to-plane
// residual; seen at a grazing angle it moves the surface along its normal. Points that few
// views saw carry their views' errors undiluted. So the fit weighs each model point by the
// inverse of the variance its views leave along its normal (Gauss-Markov: weighted least
// squares with inverse-variance weights is the best linear unbiased estimate).
#pragma once

#include <vector>

#include "arref/base/geometry.h"

namespace arref {

struct TrackingError {
  double position_m = 0.004;    // sigma per axis of a view's head position
  double orientation_deg = 0.3;  // sigma per axis of a view's head orientation
};

// One weight per point of surface (points with outward normals, in the eyes' frame): the
// inverse of the variance along its normal that the eyes facing it leave when their errors
// average in the fusion, relative to one view seeing it head-on. A point no eye faces (its normal
// tilted by the fusion) gets the smallest weight of the others. Empty (equal weights) when there
// are no eyes or no position error (a head-on view would then have none at all).
std::vector<float> TrackingErrorWeights(const PointCloud& surface, const std::vector<Vec3>& eyes,
                                        const TrackingError& error);

}  // namespace arref
