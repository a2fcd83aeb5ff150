#include "arref/track/camera_pose_history.h"

#include <algorithm>

namespace arref {

void CameraPoseHistory::Add(double time_s, const Iso3& T_world_camera) {
  if (!reports_.empty() && !(time_s > reports_.back().first)) reports_.clear();
  reports_.emplace_back(time_s, T_world_camera);
  // Keep one report at or before time_s - kKeepS, so queries up to kKeepS back still interpolate.
  while (reports_.size() > 2 && reports_[1].first <= time_s - kKeepS) reports_.pop_front();
}

std::optional<Iso3> CameraPoseHistory::At(double time_s) const {
  if (reports_.empty() || time_s < reports_.front().first || time_s > reports_.back().first) return std::nullopt;
  const auto after = std::lower_bound(reports_.begin(), reports_.end(), time_s,
                                      [](const auto& report, double t) { return report.first < t; });
  if (after->first == time_s) return after->second;
  const auto& [t0, T0] = *(after - 1);
  const auto& [t1, T1] = *after;
  const double w = (time_s - t0) / (t1 - t0);
  Iso3 T = Iso3::Identity();
  T.linear() = Quat(T0.linear()).slerp(w, Quat(T1.linear())).toRotationMatrix();
  T.translation() = (1 - w) * T0.translation() + w * T1.translation();
  return T;
}

}  // namespace arref
