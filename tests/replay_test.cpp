// `arref replay` in process (server/replay.h): a Cancel is decided by when the recording says
// the live server answered, not by how fast the replaying machine registers.
#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <tuple>
#include <utility>

#include "arref/fusion/model_reconstruction.h"
#include "arref/robot/joint_motion.h"
#include "arref/sim/cell_simulator.h"
#include "convert.h"
#include "recording.h"
#include "replay.h"
#include "test_support.h"

namespace arref::server {
namespace {

namespace pb = wire::pb;

// A recording of one session: a simulated cell's surfaces, a seed, then a registration
// request at t = 1 s and a Cancel of it at t = 1.001 s; `answered_at_s`, if set, is when the
// live server sent the request's Result.
Result<wire::Recording> CancelledSession(std::optional<double> answered_at_s) {
  ARREF_ASSIGN_OR_RETURN(const RobotModel robot, RobotModel::Load(testing::BuiltinRobotUrdf()));
  ARREF_ASSIGN_OR_RETURN(const sim::SimulatedCell cell, sim::SimulateCell(robot, sim::SmallPreset(), 4));
  wire::Recording rec;
  rec.header.set_format(wire::kRecordingFormat);
  rec.header.set_format_version(wire::kRecordingFormatVersion);
  rec.header.set_session_id(3);
  const auto add = [&](double t_s, pb::ClientMessage m) {
    pb::RecordedMessage r;
    r.set_t_s(t_s);
    *r.mutable_message() = std::move(m);
    rec.messages.push_back(std::move(r));
  };
  for (const Surface& s : cell.surfaces) {
    pb::ClientMessage m;
    *m.mutable_surface_upsert() = wire::SurfaceToProto(s, FrameConvention::kRos);
    add(0.5, std::move(m));
  }
  pb::ClientMessage request;
  pb::RegisterRequest* r = request.mutable_register_request();
  r->set_request_id(7);
  r->set_robot_id("kr5");
  r->set_method("arref-icp-fast");
  r->set_result_frame(pb::FRAME_CONVENTION_ROS);
  *r->mutable_seed()->mutable_t_world_seed() = wire::PoseToProto(cell.seeds.at(0), FrameConvention::kRos);
  r->mutable_seed()->set_frame(pb::FRAME_CONVENTION_ROS);
  add(1.0, std::move(request));
  pb::ClientMessage cancel;
  cancel.mutable_cancel()->set_request_id(7);
  add(1.001, std::move(cancel));
  if (answered_at_s) rec.answered_at_s[7] = *answered_at_s;
  return rec;
}

// The replay's answers to the request (Result status) and to the Cancel (Error code, if any).
struct CancelOutcome {
  pb::ResultStatus result = pb::RESULT_STATUS_UNSPECIFIED;
  pb::ErrorCode cancel_error = pb::ERROR_CODE_UNSPECIFIED;
  std::string message;
};

Result<CancelOutcome> Replay(const wire::Recording& rec) {
  ARREF_ASSIGN_OR_RETURN(const ServerConfig config, LoadDefaultServerConfig());
  ARREF_ASSIGN_OR_RETURN(const auto answers, ReplayRecording(rec, config));
  CancelOutcome out;
  for (const ReplayedAnswer& a : answers) {
    if (a.message.has_result()) out.result = a.message.result().status(), out.message = a.message.result().message();
    if (a.message.has_error()) out.cancel_error = a.message.error().code();
  }
  return out;
}

TEST(Replay, ACancelAfterTheLiveAnswerFindsNothingInFlight) {
  // The live server answered 0.5 ms after the request, before the Cancel came: however long
  // the registration takes here, the replay answers as the live server did.
  ASSERT_OK_AND_ASSIGN(const wire::Recording rec, CancelledSession(1.0005));
  ASSERT_OK_AND_ASSIGN(const CancelOutcome out, Replay(rec));
  EXPECT_NE(out.result, pb::RESULT_STATUS_CANCELLED) << out.message;
  EXPECT_NE(out.result, pb::RESULT_STATUS_UNSPECIFIED);
  EXPECT_EQ(out.cancel_error, pb::ERROR_CODE_UNKNOWN_REQUEST);
}

TEST(Replay, ACancelBeforeTheLiveAnswerCancels) {
  ASSERT_OK_AND_ASSIGN(const wire::Recording rec, CancelledSession(1.2));
  ASSERT_OK_AND_ASSIGN(const CancelOutcome out, Replay(rec));
  EXPECT_EQ(out.result, pb::RESULT_STATUS_CANCELLED);
  EXPECT_NE(out.message.find("before the live server answered it at 0.200 s"), std::string::npos) << out.message;
  EXPECT_EQ(out.cancel_error, pb::ERROR_CODE_UNSPECIFIED);
}

TEST(Replay, WithoutAnswerTimesTheReplayedRunDecides) {
  // A version 1 recording: the registration surely takes more than 1 ms, so the Cancel
  // arrives while it runs.
  ASSERT_OK_AND_ASSIGN(const wire::Recording rec, CancelledSession(std::nullopt));
  ASSERT_OK_AND_ASSIGN(const CancelOutcome out, Replay(rec));
  EXPECT_EQ(out.result, pb::RESULT_STATUS_CANCELLED);
  EXPECT_NE(out.message.find("the replayed run took"), std::string::npos) << out.message;
}

// Joint states that moved joint_a2 while the map was made: the replay says so and rests the fit
// on what stood still as the live session does (ChooseMovingFit on the recorded map).
// The recording with joint states (robot id, joint, position) inserted before its request, and
// the replay's Result.
Result<std::pair<wire::Recording, pb::Result>> ReplayWithJointStates(
    const std::vector<std::tuple<std::string, std::string, double>>& states) {
  ARREF_ASSIGN_OR_RETURN(wire::Recording rec, CancelledSession(1.0005));
  const auto request = std::find_if(rec.messages.begin(), rec.messages.end(),
                                    [](const pb::RecordedMessage& m) { return m.message().has_register_request(); });
  std::vector<pb::RecordedMessage> joints;
  for (const auto& [robot_id, name, q] : states) {
    pb::RecordedMessage m;
    m.set_t_s(0.8);
    m.mutable_message()->mutable_joint_state()->set_robot_id(robot_id);
    m.mutable_message()->mutable_joint_state()->add_names(name);
    m.mutable_message()->mutable_joint_state()->add_positions(q);
    joints.push_back(std::move(m));
  }
  rec.messages.insert(request, joints.begin(), joints.end());
  ARREF_ASSIGN_OR_RETURN(const ServerConfig config, LoadDefaultServerConfig());
  ARREF_ASSIGN_OR_RETURN(const auto answers, ReplayRecording(rec, config));
  const auto result = std::find_if(answers.begin(), answers.end(), [](const ReplayedAnswer& a) { return a.message.has_result(); });
  if (result == answers.end()) return Status::NotFound("the replay gave no Result");
  return std::pair{std::move(rec), result->message.result()};
}

TEST(Replay, JointsThatMovedWhileMappingAreReplayedLikeTheLiveSession) {
  ASSERT_OK_AND_ASSIGN(const auto replayed, ReplayWithJointStates({{"kr5", "joint_a2", 0.1}, {"kr5", "joint_a2", 0.5}}));
  const auto& [rec, r] = replayed;
  EXPECT_TRUE(r.joints_moved_while_mapping()) << r.message();
  EXPECT_NEAR(r.joint_motion_rad(), 0.4, 1e-9);
  TriangleMesh map;
  for (const pb::RecordedMessage& m : rec.messages)
    if (m.message().has_surface_upsert()) {
      ASSERT_OK_AND_ASSIGN(const Surface surface, wire::SurfaceFromProto(m.message().surface_upsert()));
      map.Append(surface.mesh, surface.T_world_surface);
    }
  ASSERT_OK_AND_ASSIGN(const RobotModel robot, RobotModel::Load(testing::BuiltinRobotUrdf()));
  ASSERT_OK_AND_ASSIGN(const MovingFit rule,
                       ChooseMovingFit(robot, {{"joint_a2", 0.5}}, {{"joint_a2", {0.1, 0.5}}}, kJointMotionWhileMappingRad,
                                       MedianEdgeLength(map), kMovingFitMinLeverageVoxels, kMovingFitMinMovedShare));
  const std::set<std::string> fitted(r.fitted_links().begin(), r.fitted_links().end());
  EXPECT_EQ(fitted, rule.links.value_or(std::set<std::string>{})) << r.message();
  EXPECT_NE(r.status(), pb::RESULT_STATUS_OK) << r.message();
}

// A joint state that names no robot applies to every robot (RequestJoints), but only the joints
// a robot has are its motion: joints of another arm that moved while the map was made do not
// mark this robot's Result (its flag once counted them while its fit did not).
TEST(Replay, OnlyTheRequestedRobotsJointsCountAsMotionWhileMapping) {
  ASSERT_OK_AND_ASSIGN(const auto other, ReplayWithJointStates({{"kr5", "joint_a2", 0.3}, {"", "elbow", 0.0},
                                                               {"", "elbow", 1.0}, {"kr5", "joint_a2", 0.3}}));
  EXPECT_FALSE(other.second.joints_moved_while_mapping()) << other.second.message();
  EXPECT_EQ(other.second.joint_motion_rad(), 0.0);
  EXPECT_EQ(other.second.message().find("while the map was made"), std::string::npos) << other.second.message();

  ASSERT_OK_AND_ASSIGN(const auto own, ReplayWithJointStates({{"kr5", "joint_a2", 0.3}, {"", "joint_a3", 0.0},
                                                             {"", "joint_a3", 0.6}, {"kr5", "joint_a2", 0.3}}));
  EXPECT_TRUE(own.second.joints_moved_while_mapping()) << own.second.message();
  EXPECT_NEAR(own.second.joint_motion_rad(), 0.6, 1e-9);
}

}  // namespace
}  // namespace arref::server
