// A short history of timestamped joint states, so the robot can be posed at any instant of a
// depth frame: linear interpolation between samples, a bounded hold past the newest one.
#pragma once

#include <cstddef>
#include <deque>
#include <string>
#include <vector>

#include "arref/base/status.h"
#include "arref/robot/robot_model.h"

namespace arref {

struct JointHistorySettings {
  double keep_s = 2.0;              // samples older than this behind the newest are dropped
  std::size_t max_samples = 2000;   // and never more than this many (500 Hz x 4 s)
  double max_extrapolation_s = 0.05;  // past the newest sample: linear extrapolation up to this, then hold
};

// Joint values in a fixed order (the robot's actuated joints), time in seconds on one clock.
struct JointSample {
  double time_s = 0.0;
  std::vector<double> values;
};

// Where a query fell: between two samples, before the first or after the newest one.
struct JointLookup {
  JointValues joints;
  double staleness_s = 0.0;  // how far past the newest sample the query is (0 inside the history)
  bool extrapolated = false;
};

class JointHistory {
 public:
  JointHistory(std::vector<std::string> joint_names, JointHistorySettings settings = {});

  const std::vector<std::string>& joint_names() const { return names_; }
  // Samples must come in time order per sender; one older than the newest is an error that
  // leaves the history as it was (a reordered or replayed message).
  Status Add(double time_s, const std::vector<double>& values);
  // Values by name: every actuated joint must be named.
  Status Add(double time_s, const JointValues& values);
  // The joints at time_s. FailedPrecondition while empty.
  Result<JointLookup> At(double time_s) const;
  std::size_t size() const { return samples_.size(); }
  bool empty() const { return samples_.empty(); }
  double newest_time_s() const { return samples_.empty() ? 0.0 : samples_.back().time_s; }

 private:
  JointValues ToMap(const std::vector<double>& values) const;
  std::vector<std::string> names_;
  JointHistorySettings settings_;
  std::deque<JointSample> samples_;
};

}  // namespace arref
