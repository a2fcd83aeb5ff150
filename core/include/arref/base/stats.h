// Order statistics of measured figures (latencies, errors): the one definition every table and
// summary uses, so that a median in one table means what it means in another.
#pragma once

#include <utility>
#include <vector>

namespace arref {

// The q-quantile (q in [0, 1]) by linear interpolation between the order statistics at
// q (n - 1) (Hyndman & Fan 1996, definition 7: numpy's and R's default). NaN when v is empty.
double Quantile(std::vector<double> v, double q);
inline double Median(std::vector<double> v) { return Quantile(std::move(v), 0.5); }

}  // namespace arref
