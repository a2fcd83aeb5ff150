#include "arref/base/stats.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace arref {

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  const double pos = std::clamp(q, 0.0, 1.0) * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(pos));
  const std::size_t hi = std::min(lo + 1, v.size() - 1);
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(lo), v.end());
  const double low = v[lo];
  if (hi == lo) return low;
  // The next order statistic is the smallest of those above lo.
  const double high = *std::min_element(v.begin() + static_cast<std::ptrdiff_t>(hi), v.end());
  return low + (pos - static_cast<double>(lo)) * (high - low);
}

}  // namespace arref
