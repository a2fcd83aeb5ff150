// Conversions between the server's answers and core types: a registration report or the
// status that explains why there is none becomes a Result message; joint states come in as
// core JointValues. Pure functions (no I/O), shared by the server and its tests.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "arref/base/frames.h"
#include "arref/base/status.h"
#include "arref/pipeline/pipeline.h"
#include "arref/pipeline/seedless.h"
#include "arref/robot/robot_model.h"
#include "arref/track/depth_frame.h"
#include "wire.h"

namespace arref::wire {

// The wire error code of a failed core call (anything not listed is a registration failure).
pb::ErrorCode ErrorCodeFor(const Status& status);

pb::ResultStatus ToProto(ResultStatus status);

// Every report field, with the pose in `frame` (and the internal matrix alongside).
void FillReport(const RegistrationReport& report, FrameConvention frame, pb::Result* r);

// Who asked and how long it took: the part of a Result that is not the report.
struct ResultHeader {
  std::uint64_t request_id = 0;
  std::string robot_id;
  std::uint64_t session_id = 0;
  double queue_ms = 0.0;
  double server_ms = 0.0;
  double scene_time_unix_s = 0.0;     // when the data was taken (server wall clock)
  double scene_headset_time_s = 0.0;  // its newest surface's headset timestamp
};

// The Result message of a job: the report when there is one, else a CANCELLED (status code
// kCancelled) or FAILED result carrying the status' message.
pb::ServerMessage ResultMessage(const ResultHeader& header, const std::optional<RegistrationReport>& report,
                                const Status& status, FrameConvention frame);

// A seedless result's instances (Result.candidates, primary_candidate), poses in `frame`.
void FillCandidates(const std::vector<FoundInstance>& instances, int primary, FrameConvention frame, pb::Result* r);

// Names and positions of a JointState; fails on a length mismatch or a non-finite position.
Result<JointValues> JointsFromProto(const pb::JointState& m);

// A depth frame (track/depth_frame.h) from its message: the camera turned into the optical
// frame of the internal convention, the depth bytes decoded (little-endian uint16), the time
// left on the sender's clock. InvalidArgument names what is wrong (sizes, intrinsics, pose).
Result<DepthFrame> DepthFrameFromProto(const pb::DepthFrame& m);
// ... and back, for senders (the mock headset), with the camera pose in `frame`.
pb::DepthFrame DepthFrameToProto(const DepthFrame& f, FrameConvention frame);
// T_world_optical of a camera pose as the sender gives it in `frame`, and back.
Iso3 CameraPoseToOptical(const Iso3& T_world_camera_converted, FrameConvention frame);
Iso3 CameraPoseFromOptical(const Iso3& T_world_optical, FrameConvention frame);

// A message as a shareable frame (several sessions may send the same result).
std::shared_ptr<const std::string> SharedFrame(const google::protobuf::MessageLite& message);

}  // namespace arref::wire
