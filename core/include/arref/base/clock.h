// The one clock of arref's timings (stages, queue waits, latencies): steady, in milliseconds.
#pragma once

#include <chrono>

namespace arref {

using SteadyClock = std::chrono::steady_clock;

inline double MsBetween(SteadyClock::time_point from, SteadyClock::time_point to) {
  return std::chrono::duration<double, std::milli>(to - from).count();
}
inline double MsSince(SteadyClock::time_point t) { return MsBetween(t, SteadyClock::now()); }

// Times consecutive intervals, such as the pipeline's stages or a method's steps: Lap() gives
// the milliseconds since the previous Lap (or construction, or Restart) and starts the next.
class LapTimer {
 public:
  double Lap() {
    const SteadyClock::time_point now = SteadyClock::now();
    const double ms = MsBetween(last_, now);
    last_ = now;
    return ms;
  }
  void Restart() { last_ = SteadyClock::now(); }

 private:
  SteadyClock::time_point last_ = SteadyClock::now();
};

}  // namespace arref
