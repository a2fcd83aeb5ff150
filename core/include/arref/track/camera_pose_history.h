// The camera poses a stream's frames reported, by frame time. A device whose pose is stamped
// late (head tracking's pose some time after the exposure) reports at frame time t the head's
// pose at t + latency, so the pose at an exposure lies in the reports of the frames before it:
// at frame time t - latency. Positive latencies need no frame from the future.
#pragma once

#include <deque>
#include <optional>
#include <utility>

#include "arref/base/geometry.h"

namespace arref {

class CameraPoseHistory {
 public:
  // Reports kept behind the newest: the largest latency that can be taken back.
  static constexpr double kKeepS = 1.0;

  // Reports come in time order; one not after the newest starts the history again (a replayed
  // or reordered frame), as does Clear (the world moved under the camera: poses before and after
  // a re-localisation are in different worlds and must not be blended).
  void Add(double time_s, const Iso3& T_world_camera);
  void Clear() { reports_.clear(); }
  // The reported pose at time_s: translation linear and rotation by slerp between the two reports
  // round it; none outside the reports' span.
  std::optional<Iso3> At(double time_s) const;
  // The newest report, if any.
  const std::pair<double, Iso3>* newest() const { return reports_.empty() ? nullptr : &reports_.back(); }

 private:
  std::deque<std::pair<double, Iso3>> reports_;
};

}  // namespace arref
