#include "arref/track/joint_history.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace arref {

JointHistory::JointHistory(std::vector<std::string> joint_names, JointHistorySettings settings)
    : names_(std::move(joint_names)), settings_(settings) {}

Status JointHistory::Add(double time_s, const std::vector<double>& values) {
  if (values.size() != names_.size())
    return Status::InvalidArgument(fmt::format("joint state: {} values for {} joints", values.size(), names_.size()));
  if (!std::isfinite(time_s)) return Status::InvalidArgument("joint state: the timestamp is not finite");
  for (std::size_t i = 0; i < values.size(); ++i)
    if (!std::isfinite(values[i]))
      return Status::InvalidArgument(fmt::format("joint state: joint {} is not finite", names_[i]));
  if (!samples_.empty() && time_s <= samples_.back().time_s)
    // Shortest round-trip form: the stamps as sent, however large, at no cost (a fixed
    // precision prints every digit of a 1e300 the client may send).
    return Status::InvalidArgument(fmt::format("joint state at {} s is not newer than the last one ({} s)",
                                               time_s, samples_.back().time_s));
  samples_.push_back({time_s, values});
  while (samples_.size() > settings_.max_samples || samples_.front().time_s < time_s - settings_.keep_s)
    samples_.pop_front();
  return Status::Ok();
}

Status JointHistory::Add(double time_s, const JointValues& values) {
  std::vector<double> ordered(names_.size());
  for (std::size_t i = 0; i < names_.size(); ++i) {
    const auto it = values.find(names_[i]);
    if (it == values.end()) return Status::InvalidArgument("joint state: joint " + names_[i] + " is missing");
    ordered[i] = it->second;
  }
  return Add(time_s, ordered);
}

JointValues JointHistory::ToMap(const std::vector<double>& values) const {
  JointValues out;
  for (std::size_t i = 0; i < names_.size(); ++i) out[names_[i]] = values[i];
  return out;
}

Result<JointLookup> JointHistory::At(double time_s) const {
  if (samples_.empty()) return Status::FailedPrecondition("no joint state received yet");
  JointLookup out;
  const auto lerp = [](const JointSample& a, const JointSample& b, double t) {
    const double f = (t - a.time_s) / (b.time_s - a.time_s);
    std::vector<double> v(a.values.size());
    for (std::size_t i = 0; i < v.size(); ++i) v[i] = a.values[i] + f * (b.values[i] - a.values[i]);
    return v;
  };
  if (time_s <= samples_.front().time_s) {
    out.joints = ToMap(samples_.front().values);
    return out;
  }
  if (time_s >= samples_.back().time_s) {
    out.staleness_s = time_s - samples_.back().time_s;
    if (samples_.size() < 2 || out.staleness_s == 0.0) {
      out.joints = ToMap(samples_.back().values);
      return out;
    }
    // The robot keeps moving between samples: carry its last velocity a little way, then hold.
    const JointSample& a = samples_[samples_.size() - 2];
    const JointSample& b = samples_.back();
    out.extrapolated = true;
    out.joints = ToMap(lerp(a, b, b.time_s + std::min(out.staleness_s, settings_.max_extrapolation_s)));
    return out;
  }
  const auto after = std::upper_bound(samples_.begin(), samples_.end(), time_s,
                                      [](double t, const JointSample& s) { return t < s.time_s; });
  out.joints = ToMap(lerp(*(after - 1), *after, time_s));
  return out;
}

}  // namespace arref
