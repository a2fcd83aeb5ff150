#include "convert.h"

#include <fmt/format.h>

#include <cmath>

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

void FillReport(const RegistrationReport& report, FrameConvention frame, pb::Result* r) {
  r->set_status(ToProto(report.status));
  if (report.status == ResultStatus::kFailed) r->set_error_code(pb::ERROR_CODE_REGISTRATION_FAILED);
  r->set_message(report.status_reason);
  r->set_rms_points(report.rms_points);
  r->set_score(report.score);
  r->set_margin(report.margin);
  r->set_hypotheses(report.hypotheses);
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
