// One depth image from the headset: 16-bit z-depth in millimetres, its intrinsics, where the
// camera was in the headset's world at exposure and when (the headset's clock).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/track/model_caster.h"

namespace arref {

struct DepthFrame {
  double time_s = 0.0;                 // exposure, headset clock
  DepthIntrinsics intrinsics;
  Iso3 T_world_camera = Iso3::Identity();  // optical camera frame (x right, y down, z forward)
  std::vector<std::uint16_t> depth_mm;  // row-major z-depth, 0: no return
  // > 0: the sensor measures depth modulo this (a phase-wrapping time-of-flight camera such as
  // HoloLens 2's AHAT beyond about 1 m); the tracker unwraps it near the model's prediction.
  double wrap_m = 0.0;

  float DepthAt(int u, int v) const { return 0.001f * depth_mm[static_cast<std::size_t>(v) * intrinsics.width + u]; }
};

// A depth reading in metres, unwrapped (when the sensor wraps: wrap_m > 0) to the alias nearest
// the expected depth, never nearer than the reading itself; no return (<= 0) stays as it is.
inline float UnwrappedDepth(float d, float expected, double wrap_m) {
  if (wrap_m <= 0 || d <= 0) return d;
  const double k = std::round((expected - d) / wrap_m);
  return static_cast<float>(d + std::max(0.0, k) * wrap_m);
}

// The frame is usable: intrinsics valid, one depth per pixel, a finite pose and time.
Status CheckDepthFrame(const DepthFrame& frame);

}  // namespace arref
