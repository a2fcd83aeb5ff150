#include "wire.h"

#include <fmt/format.h>
#include <google/protobuf/io/zero_copy_stream_impl_lite.h>
#include <google/protobuf/util/delimited_message_util.h>

#include <cmath>
#include <limits>

namespace arref::wire {

std::string EncodeFrame(const google::protobuf::MessageLite& message) {
  std::string out;
  {
    google::protobuf::io::StringOutputStream stream(&out);
    google::protobuf::util::SerializeDelimitedToZeroCopyStream(message, &stream);
  }  // the stream trims `out` to the bytes written when destroyed
  return out;
}

// Same varint as protobuf's delimited format, decoded by hand so that an asynchronous reader
// can tell "need more bytes" from "garbage" and refuse huge lengths before buffering them.
FrameHeader DecodeFrameHeader(const std::uint8_t* data, std::size_t size, std::uint64_t max_body_bytes) {
  FrameHeader h;
  std::uint64_t value = 0;
  for (std::size_t i = 0; i < size && i < 10; ++i) {
    value |= static_cast<std::uint64_t>(data[i] & 0x7f) << (7 * i);
    // Lengths above the maximum are refused as soon as the prefix shows it, even before it
    // ends, and before a prefix too long to be a varint: the verdict must not depend on how
    // the stream was cut into reads (found by tests/fuzz/frame_decoder_fuzz.cpp). The length
    // reported is as much of it as has arrived.
    if (value > max_body_bytes) {
      for (std::size_t k = i; (data[k] & 0x80) != 0 && k + 1 < size && k + 1 < 10; ++k)
        value |= static_cast<std::uint64_t>(data[k + 1] & 0x7f) << (7 * (k + 1));
      h.state = FrameHeader::State::kTooLarge;
      h.body_bytes = value;
      return h;
    }
    if ((data[i] & 0x80) == 0) {
      h.header_bytes = i + 1;
      h.body_bytes = value;
      h.state = FrameHeader::State::kComplete;
      return h;
    }
  }
  if (size >= 10) h.state = FrameHeader::State::kBadVarint;
  return h;
}

pb::FrameConvention ToProto(FrameConvention frame) {
  return frame == FrameConvention::kRos ? pb::FRAME_CONVENTION_ROS : pb::FRAME_CONVENTION_UNITY;
}

Result<FrameConvention> FromProto(pb::FrameConvention frame) {
  switch (frame) {
    case pb::FRAME_CONVENTION_ROS: return FrameConvention::kRos;
    case pb::FRAME_CONVENTION_UNITY: return FrameConvention::kUnity;
    case pb::FRAME_CONVENTION_UNSPECIFIED: return Status::InvalidArgument("frame convention not set (UNITY or ROS required)");
    default:
      return Status::InvalidArgument(
          fmt::format("frame convention {} is not one of UNITY (1) or ROS (2)", static_cast<int>(frame)));
  }
}

pb::Pose PoseToProto(const Iso3& T, FrameConvention frame) {
  Vec3 p;
  Quat q;
  PoseFromRos(T, frame, &p, &q);
  pb::Pose pose;
  pose.mutable_position()->set_x(p.x());
  pose.mutable_position()->set_y(p.y());
  pose.mutable_position()->set_z(p.z());
  pose.mutable_orientation()->set_x(q.x());
  pose.mutable_orientation()->set_y(q.y());
  pose.mutable_orientation()->set_z(q.z());
  pose.mutable_orientation()->set_w(q.w());
  return pose;
}

Result<Iso3> PoseFromProto(const pb::Pose& pose, FrameConvention frame) {
  if (!pose.has_position() || !pose.has_orientation())
    return Status::InvalidArgument("pose needs both position and orientation");
  const Vec3 p(pose.position().x(), pose.position().y(), pose.position().z());
  const auto& o = pose.orientation();
  Quat q(o.w(), o.x(), o.y(), o.z());
  if (!p.allFinite() || !q.coeffs().allFinite()) return Status::InvalidArgument("pose has non-finite values");
  if (q.norm() < 1e-6) return Status::InvalidArgument("pose orientation is a zero quaternion");
  q.normalize();
  return PoseToRos(p, q, frame);
}

pb::SurfaceUpsert SurfaceToProto(const Surface& surface, FrameConvention frame, double quantize_scale) {
  TriangleMesh mesh = surface.mesh;
  MeshFromRos(mesh, frame);
  pb::SurfaceUpsert m;
  m.set_surface_id(surface.id);
  m.set_frame(ToProto(frame));
  m.set_timestamp_s(surface.timestamp_s);
  *m.mutable_t_world_surface() = PoseToProto(surface.T_world_surface, frame);
  if (quantize_scale > 0) {
    m.set_vertex_scale(static_cast<float>(quantize_scale));
    m.mutable_quantized_vertices()->Reserve(static_cast<int>(mesh.vertices.size() * 3));
    for (const auto& v : mesh.vertices)
      for (int k = 0; k < 3; ++k) m.add_quantized_vertices(static_cast<std::int32_t>(std::lround(v[k] / quantize_scale)));
  } else {
    m.mutable_vertices()->Reserve(static_cast<int>(mesh.vertices.size() * 3));
    for (const auto& v : mesh.vertices)
      for (int k = 0; k < 3; ++k) m.add_vertices(v[k]);
  }
  m.mutable_triangles()->Reserve(static_cast<int>(mesh.triangles.size() * 3));
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) m.add_triangles(t[k]);
  return m;
}

namespace {

Status ReadVertices(const pb::SurfaceUpsert& m, std::vector<Vec3f>* out) {
  const bool plain = m.vertices_size() > 0, quantized = m.quantized_vertices_size() > 0;
  if (plain == quantized) return Status::InvalidArgument("exactly one of vertices and quantized_vertices must be set");
  const int n = plain ? m.vertices_size() : m.quantized_vertices_size();
  if (n % 3 != 0) return Status::InvalidArgument("vertex array length " + std::to_string(n) + " is not a multiple of 3");
  const float scale = m.vertex_scale();
  if (quantized && !(std::isfinite(scale) && scale > 0))
    return Status::InvalidArgument("quantized vertices need vertex_scale > 0");
  out->resize(n / 3);
  for (int i = 0; i < n; ++i) {
    float value;
    if (plain) {
      value = m.vertices(i);
    } else {
      const std::int32_t q = m.quantized_vertices(i);
      if (q < std::numeric_limits<std::int16_t>::min() || q > std::numeric_limits<std::int16_t>::max())
        return Status::InvalidArgument("quantized vertex value " + std::to_string(q) + " at " + std::to_string(i) +
                                       " is outside int16");
      value = static_cast<float>(q) * scale;
    }
    (*out)[i / 3][i % 3] = value;
  }
  return Status::Ok();
}

}  // namespace

Result<Surface> SurfaceFromProto(const pb::SurfaceUpsert& m) {
  ARREF_ASSIGN_OR_RETURN(const FrameConvention frame, FromProto(m.frame()));
  Surface s;
  s.id = m.surface_id();
  s.timestamp_s = m.timestamp_s();
  ARREF_RETURN_IF_ERROR(ReadVertices(m, &s.mesh.vertices));
  if (m.triangles_size() % 3 != 0)
    return Status::InvalidArgument("triangle index array length " + std::to_string(m.triangles_size()) +
                                   " is not a multiple of 3");
  s.mesh.triangles.resize(m.triangles_size() / 3);
  for (int i = 0; i < m.triangles_size(); ++i) s.mesh.triangles[i / 3][i % 3] = m.triangles(i);
  if (!m.has_t_world_surface()) return Status::InvalidArgument("T_world_surface missing");
  auto T = PoseFromProto(m.t_world_surface(), frame);
  if (!T.ok()) return T.status().WithContext("T_world_surface");
  s.T_world_surface = *T;
  MeshToRos(s.mesh, frame);
  return s;
}

pb::HeadPath HeadPathToProto(const std::vector<Vec3>& positions_world, FrameConvention frame) {
  pb::HeadPath m;
  m.set_frame(ToProto(frame));
  for (const Vec3& p : positions_world) {
    const Vec3 q = PositionFromRos(p, frame);
    pb::Vec3* v = m.add_positions();
    v->set_x(q.x()), v->set_y(q.y()), v->set_z(q.z());
  }
  return m;
}

Result<std::vector<Vec3>> HeadPathFromProto(const pb::HeadPath& path, std::size_t max_positions) {
  auto frame = FromProto(path.frame());
  if (!frame.ok()) return frame.status().WithContext("head_path.frame");
  if (static_cast<std::size_t>(path.positions_size()) > max_positions)
    return Status::InvalidArgument(fmt::format("head_path has {} positions, at most {} allowed", path.positions_size(),
                                               max_positions));
  std::vector<Vec3> out;
  out.reserve(static_cast<std::size_t>(path.positions_size()));
  for (const pb::Vec3& v : path.positions()) {
    const Vec3 p(v.x(), v.y(), v.z());
    if (!p.allFinite())
      return Status::InvalidArgument(fmt::format("head_path.positions[{}] is not finite", out.size()));
    out.push_back(PositionToRos(p, *frame));
  }
  return out;
}

void MatrixToProto(const Iso3& T, google::protobuf::RepeatedField<double>* out) {
  out->Clear();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out->Add(T.matrix()(r, c));
}

Result<Iso3> MatrixFromProto(const google::protobuf::RepeatedField<double>& m) {
  if (m.size() != 16) return Status::InvalidArgument("matrix needs 16 values, got " + std::to_string(m.size()));
  Iso3 T;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) T.matrix()(r, c) = m.Get(4 * r + c);
  return T;
}

const char* ErrorCodeName(pb::ErrorCode code) {
  const std::string& name = pb::ErrorCode_Name(code);
  return name.c_str();  // protobuf keeps enum names for the process lifetime
}

pb::ServerMessage ErrorMessage(pb::ErrorCode code, const std::string& message, std::uint64_t request_id,
                               std::uint64_t surface_id, bool fatal) {
  pb::ServerMessage reply;
  auto* e = reply.mutable_error();
  e->set_code(code);
  e->set_message(message);
  e->set_request_id(request_id);
  e->set_surface_id(surface_id);
  e->set_fatal(fatal);
  return reply;
}

}  // namespace arref::wire
