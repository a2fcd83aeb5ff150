#include "convert.h"

#include <fmt/format.h>

#include <cmath>
#include <numbers>

namespace arref::wire {

pb::ErrorCode ErrorCodeFor(const Status& status) {
  switch (status.code()) {
    case StatusCode::kInvalidArgument: return pb::ERROR_CODE_INVALID_ARGUMENT;
    case StatusCode::kCancelled: return pb::ERROR_CODE_CANCELLED;
    case StatusCode::kResourceExhausted: return pb::ERROR_CODE_LIMIT_EXCEEDED;
    case StatusCode::kInternal: return pb::ERROR_CODE_INTERNAL;
    default: return pb::ERROR_CODE_REGISTRATION_FAILED;
  }
}

pb::ResultStatus ToProto(ResultStatus status) {
  switch (status) {
    case ResultStatus::kOk: return pb::RESULT_STATUS_OK;
    case ResultStatus::kLowConfidence: return pb::RESULT_STATUS_LOW_CONFIDENCE;
    case ResultStatus::kFailed: return pb::RESULT_STATUS_FAILED;
  }
  return pb::RESULT_STATUS_FAILED;
}

namespace {
void FillPrecision(const FitPrecision& p, pb::Result* r) {
  if (!p.valid) return;
  r->set_expected_error_m(p.expected_error_m);
  r->set_fit_error_m(p.fit_error_m);
  r->set_map_error_m(p.map_error_m);
  r->set_surface_error_m(p.surface_error_m);
  r->set_sigma_horizontal_m(p.sigma_horizontal_m());
  r->set_sigma_vertical_m(p.sigma_vertical_m());
  r->set_sigma_yaw_deg(p.sigma_yaw_rad() * 180.0 / std::numbers::pi);
  const Eigen::Matrix4d C = p.covariance();
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) r->add_covariance(C(i, j));
}
}  // namespace

void FillReport(const RegistrationReport& report, FrameConvention frame, pb::Result* r) {
  r->set_status(ToProto(report.status));
  if (report.status == ResultStatus::kFailed) r->set_error_code(pb::ERROR_CODE_REGISTRATION_FAILED);
  r->set_message(report.status_reason);
  r->set_rms_points(report.rms_points);
  r->set_score(report.score);
  r->set_margin(report.margin);
  r->set_hypotheses(report.hypotheses);
  FillPrecision(report.precision, r);
  for (const auto& stage : report.stages_run) r->add_stages(stage);
  *r->mutable_t_world_base() = PoseToProto(report.T_world_base, frame);
  r->set_frame(ToProto(frame));
  MatrixToProto(report.T_world_base, r->mutable_t_world_base_internal());
  r->set_rms_m(report.rms_m);
  r->set_inlier_fraction(report.inlier_fraction);
  r->set_iterations(report.iterations);
  r->set_converged(report.converged);
  r->set_method(report.method);
  for (const auto& t : report.timings) {
    auto* timing = r->add_timings();
    timing->set_stage(t.stage);
    timing->set_ms(t.ms);
  }
  r->set_scene_triangles(report.scene_triangles);
  r->set_scene_points(report.scene_points);
  r->set_model_points(report.model_points);
}

pb::ServerMessage ResultMessage(const ResultHeader& header, const std::optional<RegistrationReport>& report,
                                const Status& status, FrameConvention frame) {
  pb::ServerMessage message;
  pb::Result* r = message.mutable_result();
  r->set_request_id(header.request_id);
  r->set_robot_id(header.robot_id);
  r->set_session_id(header.session_id);
  r->set_queue_ms(header.queue_ms);
  r->set_server_ms(header.server_ms);
  r->set_scene_time_unix_s(header.scene_time_unix_s);
  r->set_scene_headset_time_s(header.scene_headset_time_s);
  if (report) {
    FillReport(*report, frame, r);
  } else {
    const bool cancelled = status.code() == StatusCode::kCancelled;
    r->set_status(cancelled ? pb::RESULT_STATUS_CANCELLED : pb::RESULT_STATUS_FAILED);
    r->set_error_code(ErrorCodeFor(status));
    r->set_message(status.message());
  }
  return message;
}

void FillCandidates(const std::vector<FoundInstance>& instances, int primary, FrameConvention frame, pb::Result* r) {
  for (const FoundInstance& f : instances) {
    pb::Candidate* c = r->add_candidates();
    *c->mutable_t_world_base() = PoseToProto(f.report.T_world_base, frame);
    MatrixToProto(f.report.T_world_base, c->mutable_t_world_base_internal());
    c->set_status(ToProto(f.report.status));
    c->set_message(f.report.status_reason);
    c->set_score(f.report.score);
    c->set_margin(f.report.margin);
    c->set_inlier_fraction(f.report.inlier_fraction);
    if (f.report.precision.valid) c->set_expected_error_m(f.report.precision.expected_error_m);
  }
  r->set_primary_candidate(primary);
}

Result<JointValues> JointsFromProto(const pb::JointState& m) {
  if (m.names_size() != m.positions_size())
    return Status::InvalidArgument(fmt::format("joint state has {} names but {} positions", m.names_size(),
                                               m.positions_size()));
  JointValues joints;
  for (int i = 0; i < m.names_size(); ++i) {
    if (!std::isfinite(m.positions(i)))
      return Status::InvalidArgument("joint '" + m.names(i) + "' position is not finite");
    joints[m.names(i)] = m.positions(i);
  }
  return joints;
}

std::shared_ptr<const std::string> SharedFrame(const google::protobuf::MessageLite& message) {
  return std::make_shared<const std::string>(EncodeFrame(message));
}

}  // namespace arref::wire

namespace arref::wire {
namespace {
// The optical axes (x right, y down, z forward) in the frame a Unity camera pose becomes once
// converted (x forward, y left, z up: frames.h maps Unity's right/up/forward so).
Eigen::Matrix3d R_flu_optical() {
  Eigen::Matrix3d R;
  R << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  return R;
}
}  // namespace

Iso3 CameraPoseToOptical(const Iso3& T, FrameConvention frame) {
  if (frame == FrameConvention::kRos) return T;
  Iso3 out = T;
  out.linear() = T.linear() * R_flu_optical();
  return out;
}

Iso3 CameraPoseFromOptical(const Iso3& T, FrameConvention frame) {
  if (frame == FrameConvention::kRos) return T;
  Iso3 out = T;
  out.linear() = T.linear() * R_flu_optical().transpose();
  return out;
}

Result<DepthFrame> DepthFrameFromProto(const pb::DepthFrame& m) {
  DepthFrame f;
  f.intrinsics.width = static_cast<int>(m.width());
  f.intrinsics.height = static_cast<int>(m.height());
  f.intrinsics.fx = m.fx(), f.intrinsics.fy = m.fy(), f.intrinsics.cx = m.cx(), f.intrinsics.cy = m.cy();
  if (m.width() == 0 || m.height() == 0 || m.width() > 4096 || m.height() > 4096)
    return Status::InvalidArgument(fmt::format("DepthFrame: {}x{} pixels (1-4096 each)", m.width(), m.height()));
  const std::size_t pixels = static_cast<std::size_t>(m.width()) * m.height();
  if (m.depth_mm().size() != 2 * pixels)
    return Status::InvalidArgument(fmt::format("DepthFrame: depth_mm has {} bytes, {}x{} pixels need {}",
                                               m.depth_mm().size(), m.width(), m.height(), 2 * pixels));
  const auto frame = FromProto(m.frame());
  if (!frame.ok()) return frame.status().WithContext("DepthFrame.frame");
  auto T = PoseFromProto(m.t_world_camera(), *frame);
  if (!T.ok()) return T.status().WithContext("DepthFrame.T_world_camera");
  f.T_world_camera = CameraPoseToOptical(*T, *frame);
  f.time_s = m.timestamp_s();
  f.wrap_m = m.wrap_m();
  f.depth_mm.resize(pixels);
  const auto* bytes = reinterpret_cast<const unsigned char*>(m.depth_mm().data());
  for (std::size_t i = 0; i < pixels; ++i)
    f.depth_mm[i] = static_cast<std::uint16_t>(bytes[2 * i] | (bytes[2 * i + 1] << 8));
  if (auto st = CheckDepthFrame(f); !st.ok()) return st;
  return f;
}

pb::DepthFrame DepthFrameToProto(const DepthFrame& f, FrameConvention frame) {
  pb::DepthFrame m;
  m.set_width(static_cast<std::uint32_t>(f.intrinsics.width));
  m.set_height(static_cast<std::uint32_t>(f.intrinsics.height));
  m.set_fx(f.intrinsics.fx), m.set_fy(f.intrinsics.fy), m.set_cx(f.intrinsics.cx), m.set_cy(f.intrinsics.cy);
  std::string bytes(2 * f.depth_mm.size(), '\0');
  for (std::size_t i = 0; i < f.depth_mm.size(); ++i) {
    bytes[2 * i] = static_cast<char>(f.depth_mm[i] & 0xff);
    bytes[2 * i + 1] = static_cast<char>(f.depth_mm[i] >> 8);
  }
  m.set_depth_mm(std::move(bytes));
  *m.mutable_t_world_camera() = PoseToProto(CameraPoseFromOptical(f.T_world_camera, frame), frame);
  m.set_frame(ToProto(frame));
  m.set_timestamp_s(f.time_s);
  m.set_wrap_m(f.wrap_m);
  return m;
}

}  // namespace arref::wire
