#include "arref/track/clock_sync.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace arref {

Status ClockOffsetEstimator::Add(const ClockExchange& e) {
  if (!std::isfinite(e.t0) || !std::isfinite(e.t1) || !std::isfinite(e.t2) || !std::isfinite(e.t3))
    return Status::InvalidArgument("clock exchange: a time is not finite");
  if (e.t3 < e.t0 || e.t2 < e.t1)
    return Status::InvalidArgument(fmt::format("clock exchange runs backwards (t0 {} t1 {} t2 {} t3 {})", e.t0, e.t1, e.t2, e.t3));
  const double delay = (e.t3 - e.t0) - (e.t2 - e.t1);
  exchanges_.push_back({0.5 * ((e.t1 - e.t0) + (e.t2 - e.t3)), std::max(0.0, delay)});
  while (exchanges_.size() > window_) exchanges_.pop_front();
  return Status::Ok();
}

const ClockOffsetEstimator::Sample* ClockOffsetEstimator::Best() const {
  if (exchanges_.empty()) return nullptr;
  return &*std::min_element(exchanges_.begin(), exchanges_.end(),
                            [](const Sample& a, const Sample& b) { return a.delay < b.delay; });
}

double ClockOffsetEstimator::offset_s() const { return Best() ? Best()->offset : 0.0; }
double ClockOffsetEstimator::uncertainty_s() const { return Best() ? 0.5 * Best()->delay : 0.0; }

}  // namespace arref
