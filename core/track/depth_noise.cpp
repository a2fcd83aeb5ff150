#include "arref/track/depth_noise.h"

#include <cmath>
#include <vector>

#include "arref/base/stats.h"

namespace arref {

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
  if (ratios.size() < min_samples) return std::nullopt;
  return 1.4826 * static_cast<double>(UpperMiddle(ratios)) / std::sqrt(6.0);
}

void DepthNoiseEstimate::Add(double fraction) {
  if (!std::isfinite(fraction)) return;
  recent_.push_back(fraction);
  while (recent_.size() > frames_) recent_.pop_front();
  std::vector<double> v(recent_.begin(), recent_.end());
  median_ = UpperMiddle(v);
}

}  // namespace arref
