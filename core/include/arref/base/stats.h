// Order statistics of measured figures (latencies, errors): the one definition every table and
// summary uses, so that a median in one table means what it means in another.
#pragma once

#include <algorithm>
#include <cstddef>
#include <utility>
#include <vector>

namespace arref {

// The q-quantile (q in [0, 1]) by linear interpolation between the order statistics at
// q (n - 1) (Hyndman & Fan 1996, definition 7: numpy's and R's default). NaN when v is empty.
double Quantile(std::vector<double> v, double q);
inline double Median(std::vector<double> v) { return Quantile(std::move(v), 0.5); }

// The upper middle element (rank n / 2), found in place: the median of robust estimators on hot
// paths (a scale from residuals, a mesh's edge length), where the interpolation Median does for
// tables is not part of the estimator. Reorders v, which must not be empty.
template <typename T>
T UpperMiddle(std::vector<T>& v) {
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

}  // namespace arref
