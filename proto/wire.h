// Helpers shared by the server and the clients: framing (protobuf varint length prefix) and
// conversions between wire messages and core types. Includes the generated protocol header,
// so keep it out of widely included headers.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "arref/base/frames.h"
#include "arref/base/geometry.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/base/status.h"
#include "arref/v1/arref.pb.h"

namespace arref::wire {

namespace pb = ::arref::v1;

constexpr std::uint32_t kProtocolVersion = pb::PROTOCOL_VERSION_CURRENT;

// The message with its varint length prefix (SerializeDelimitedToZeroCopyStream).
std::string EncodeFrame(const google::protobuf::MessageLite& message);

// Incremental decoding of the length prefix of a byte stream.
struct FrameHeader {
  enum class State { kNeedMore, kComplete, kTooLarge, kBadVarint } state = State::kNeedMore;
  std::size_t header_bytes = 0;  // bytes of the varint
  std::uint64_t body_bytes = 0;  // declared length of the message
};
FrameHeader DecodeFrameHeader(const std::uint8_t* data, std::size_t size, std::uint64_t max_body_bytes);

pb::FrameConvention ToProto(FrameConvention frame);
Result<FrameConvention> FromProto(pb::FrameConvention frame);

// Pose (position + quaternion in `frame`) of an internal transform, and back. FromProto checks
// finiteness and normalises the quaternion.
pb::Pose PoseToProto(const Iso3& T, FrameConvention frame);
Result<Iso3> PoseFromProto(const pb::Pose& pose, FrameConvention frame);

// A HoloLens-like surface message from an internal surface, and back (validated by the caller
// through SpatialMesh::Upsert). quantize_scale > 0 sends int16 vertices with that step.
pb::SurfaceUpsert SurfaceToProto(const Surface& surface, FrameConvention frame, double quantize_scale = 0.0);
Result<Surface> SurfaceFromProto(const pb::SurfaceUpsert& message);

// Head positions in the internal frame, and back. FromProto checks the frame, the count
// (at most max_positions) and finiteness, naming the first bad position.
pb::HeadPath HeadPathToProto(const std::vector<Vec3>& positions_world, FrameConvention frame);
Result<std::vector<Vec3>> HeadPathFromProto(const pb::HeadPath& path, std::size_t max_positions);

// Row-major 4x4 of an internal transform.
void MatrixToProto(const Iso3& T, google::protobuf::RepeatedField<double>* out);
Result<Iso3> MatrixFromProto(const google::protobuf::RepeatedField<double>& m);

const char* ErrorCodeName(pb::ErrorCode code);
// An Error message; ids 0 where it answers no request or surface. fatal: the session ends.
pb::ServerMessage ErrorMessage(pb::ErrorCode code, const std::string& message, std::uint64_t request_id = 0,
                               std::uint64_t surface_id = 0, bool fatal = false);

}  // namespace arref::wire
