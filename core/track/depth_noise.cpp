#include "arref/track/depth_noise.h"

#include <cmath>
#include <vector>

#include "arref/base/stats.h"

namespace arref {
namespace {

// sigma / range from second differences over range: 6 sigma^2 of variance on a smooth surface,
// edges and missing returns outliers for the median (MAD, 1.4826 per sigma).
std::optional<double> SigmaOfSecondDifferences(std::vector<float>& ratios, std::size_t min_samples) {
  if (ratios.size() < min_samples) return std::nullopt;
  return 1.4826 * static_cast<double>(UpperMiddle(ratios)) / std::sqrt(6.0);
}

// a - b modulo the wrap, into [-wrap / 2, wrap / 2).
float WrappedDifference(float a, float b, float wrap) {
  const float d = a - b;
  return d - wrap * std::floor(d / wrap + 0.5f);
}

}  // namespace

std::optional<double> FrameDepthNoise(const DepthFrame& frame, int row_step, std::size_t min_samples) {
  const DepthIntrinsics& c = frame.intrinsics;
  if (frame.wrap_m > 0 || c.width < 3 || row_step < 1) return std::nullopt;
  std::vector<float> ratios;
  ratios.reserve(static_cast<std::size_t>(c.height / row_step + 1) * static_cast<std::size_t>(c.width));
  for (int v = 0; v < c.height; v += row_step)
    for (int u = 1; u + 1 < c.width; ++u) {
      const float a = frame.DepthAt(u - 1, v), b = frame.DepthAt(u, v), d = frame.DepthAt(u + 1, v);
      if (a <= 0 || b <= 0 || d <= 0) continue;
      ratios.push_back(std::abs(a - 2 * b + d) / b);
    }
  return SigmaOfSecondDifferences(ratios, min_samples);
}

std::optional<double> WrappedFrameDepthNoise(const DepthFrame& frame, const ModelView& expected, std::size_t min_samples) {
  const DepthIntrinsics& c = frame.intrinsics;
  const int s = expected.stride;
  if (!(frame.wrap_m > 0) || s < 1 || expected.width != c.width || expected.height != c.height) return std::nullopt;
  const int gw = c.width / s, gh = c.height / s;
  if (expected.z_depth.size() < static_cast<std::size_t>(gw) * static_cast<std::size_t>(gh)) return std::nullopt;
  const float wrap = static_cast<float>(frame.wrap_m);
  std::vector<float> ratios;
  for (int gv = 0; gv < gh; ++gv)
    for (int gu = 0; gu < gw; ++gu) {
      const float z = expected.z_depth[static_cast<std::size_t>(gv) * gw + gu];
      const int u = gu * s, v = gv * s;
      if (z <= 0 || u < 1 || u + 1 >= c.width) continue;
      const float a = frame.DepthAt(u - 1, v), b = frame.DepthAt(u, v), d = frame.DepthAt(u + 1, v);
      if (a <= 0 || b <= 0 || d <= 0) continue;
      const float range = UnwrappedDepth(b, z, frame.wrap_m);
      ratios.push_back(std::abs(WrappedDifference(d, b, wrap) - WrappedDifference(b, a, wrap)) / range);
    }
  return SigmaOfSecondDifferences(ratios, min_samples);
}

void DepthNoiseEstimate::Add(double fraction) {
  if (!std::isfinite(fraction)) return;
  recent_.push_back(fraction);
  while (recent_.size() > frames_) recent_.pop_front();
  std::vector<double> v(recent_.begin(), recent_.end());
  median_ = UpperMiddle(v);
}

}  // namespace arref
