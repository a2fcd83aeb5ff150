// The tracking messages of one session (TrackRequest, DepthFrame, ClockReport, and the joint
// stream a timestamped JointState feeds), handled the same way by the live session and by the
// offline replay: each validates its message, hands it to the TrackingService and returns the
// Error to answer with, if any.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "arref/base/geometry.h"
#include "robot_registry.h"
#include "tracking_service.h"
#include "wire.h"

namespace arref::server {

struct Refusal {
  wire::pb::ErrorCode code = wire::pb::ERROR_CODE_UNSPECIFIED;
  std::string message;
};

// Starts (or stops) tracking for `session`; the seed is the request's, else the session's
// last SeedPose.
std::optional<Refusal> HandleTrackRequest(const wire::pb::TrackRequest& m, const RobotRegistry& robots,
                                          TrackingService& tracking, const std::shared_ptr<TrackingSink>& session,
                                          const std::optional<Iso3>& session_seed);
std::optional<Refusal> HandleDepthFrame(const wire::pb::DepthFrame& m, TrackingService& tracking,
                                        std::uint64_t session_id);
std::optional<Refusal> HandleClockReport(const wire::pb::ClockReport& m, TrackingService& tracking,
                                         std::uint64_t session_id);
// A JointState already accepted (ReadJointState) that names its robot and carries a timestamp
// is also a sample of that robot's joint stream: `complete` is JointStateOutcome::complete.
std::optional<Refusal> FeedJointStream(const wire::pb::JointState& m, const JointValues& complete,
                                       TrackingService& tracking, std::uint64_t session_id);

}  // namespace arref::server
