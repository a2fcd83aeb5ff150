// The offset between two clocks from timestamped round trips, as NTP estimates it (RFC 5905,
// on-wire protocol and clock filter): the exchange with the shortest round trip among the
// recent ones is the least delayed, so its offset is the best.
#pragma once

#include <cstddef>
#include <deque>

#include "arref/base/status.h"

namespace arref {

struct ClockExchange {
  double t0 = 0.0;  // request sent, the peer's clock
  double t1 = 0.0;  // request received, our clock
  double t2 = 0.0;  // reply sent, our clock
  double t3 = 0.0;  // reply received, the peer's clock
};

class ClockOffsetEstimator {
 public:
  explicit ClockOffsetEstimator(std::size_t window = 16) : window_(window) {}
  // InvalidArgument for an exchange whose times run backwards (t3 < t0 or t2 < t1).
  Status Add(const ClockExchange& e);
  bool has_estimate() const { return !exchanges_.empty(); }
  // Our clock minus the peer's: a peer time plus this is our time.
  double offset_s() const;
  // Half the shortest round trip: the offset is within this of the truth if the delays are.
  double uncertainty_s() const;
  std::size_t exchanges() const { return exchanges_.size(); }

 private:
  struct Sample { double offset, delay; };
  const Sample* Best() const;
  std::size_t window_;
  std::deque<Sample> exchanges_;
};

}  // namespace arref
