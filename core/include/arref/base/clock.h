// The one clock of arref's timings (stages, queue waits, latencies): steady, in milliseconds.
#pragma once

#include <chrono>

namespace arref {

using SteadyClock = std::chrono::steady_clock;

inline double MsBetween(SteadyClock::time_point from, SteadyClock::time_point to) {
  return std::chrono::duration<double, std::milli>(to - from).count();
}
inline double MsSince(SteadyClock::time_point t) { return MsBetween(t, SteadyClock::now()); }

}  // namespace arref
