// Protocol <-> core conversions: poses round-trip in both frame conventions, results carry
// a report or the status that replaces it, joint states are checked.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "arref/base/frames.h"
#include "convert.h"
#include "wire.h"

namespace arref::wire {
namespace {

Iso3 SomePose() {
  Iso3 T = Iso3::Identity();
  T.translate(Vec3(1.25, -0.5, 0.75));
  T.rotate(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
  return T;
}

TEST(WireConvert, FrameConventionRoundTrips) {
  for (FrameConvention f : {FrameConvention::kUnity, FrameConvention::kRos}) {
    auto back = FromProto(ToProto(f));
    ASSERT_TRUE(back.ok());
    EXPECT_EQ(*back, f);
  }
  EXPECT_EQ(ToProto(FrameConvention::kUnity), pb::FRAME_CONVENTION_UNITY);
  EXPECT_EQ(ToProto(FrameConvention::kRos), pb::FRAME_CONVENTION_ROS);
  auto unset = FromProto(pb::FRAME_CONVENTION_UNSPECIFIED);
  ASSERT_FALSE(unset.ok());
  EXPECT_EQ(unset.status().code(), StatusCode::kInvalidArgument);
}

TEST(WireConvert, PoseRoundTripsInRosAndUnityFrames) {
  const Iso3 T = SomePose();
  for (FrameConvention f : {FrameConvention::kUnity, FrameConvention::kRos}) {
    const pb::Pose pose = PoseToProto(T, f);
    auto back = PoseFromProto(pose, f);
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    EXPECT_TRUE(back->isApprox(T, 1e-12)) << FrameConventionName(f);
  }
  // ROS is the internal frame: its numbers are the transform's own.
  const pb::Pose ros = PoseToProto(T, FrameConvention::kRos);
  EXPECT_DOUBLE_EQ(ros.position().x(), 1.25);
  EXPECT_DOUBLE_EQ(ros.position().y(), -0.5);
  EXPECT_DOUBLE_EQ(ros.position().z(), 0.75);
  // Unity's numbers are the same point in Unity's basis.
  const pb::Pose unity = PoseToProto(T, FrameConvention::kUnity);
  const Vec3 expected = PositionFromRos(T.translation(), FrameConvention::kUnity);
  EXPECT_DOUBLE_EQ(unity.position().x(), expected.x());
  EXPECT_DOUBLE_EQ(unity.position().y(), expected.y());
  EXPECT_DOUBLE_EQ(unity.position().z(), expected.z());
  EXPECT_FALSE(Vec3(unity.position().x(), unity.position().y(), unity.position().z()).isApprox(T.translation()));
  // Reading a Unity pose as ROS gives a different transform: the frame matters.
  auto misread = PoseFromProto(unity, FrameConvention::kRos);
  ASSERT_TRUE(misread.ok());
  EXPECT_FALSE(misread->isApprox(T, 1e-6));
}

TEST(WireConvert, PoseFromProtoChecksItsInput) {
  pb::Pose pose = PoseToProto(SomePose(), FrameConvention::kUnity);
  pose.mutable_orientation()->set_w(pose.orientation().w() * 3);  // not unit: normalised
  auto scaled = PoseFromProto(pose, FrameConvention::kUnity);
  ASSERT_TRUE(scaled.ok());
  EXPECT_FALSE(scaled->isApprox(SomePose(), 1e-6)) << "a different rotation once normalised";
  pose.mutable_orientation()->set_x(0), pose.mutable_orientation()->set_y(0);
  pose.mutable_orientation()->set_z(0), pose.mutable_orientation()->set_w(0);
  EXPECT_FALSE(PoseFromProto(pose, FrameConvention::kUnity).ok());
  pb::Pose nan = PoseToProto(SomePose(), FrameConvention::kRos);
  nan.mutable_position()->set_z(std::numeric_limits<double>::quiet_NaN());
  EXPECT_FALSE(PoseFromProto(nan, FrameConvention::kRos).ok());
}

TEST(WireConvert, MatrixRoundTrips) {
  pb::Result r;
  MatrixToProto(SomePose(), r.mutable_t_world_base_internal());
  ASSERT_EQ(r.t_world_base_internal_size(), 16);
  auto back = MatrixFromProto(r.t_world_base_internal());
  ASSERT_TRUE(back.ok());
  EXPECT_TRUE(back->isApprox(SomePose(), 0.0));
}

TEST(WireConvert, ResultMessageOfAReportInEitherFrame) {
  RegistrationReport report;
  report.status = ResultStatus::kLowConfidence;
  report.status_reason = "margin below threshold";
  report.T_world_base = SomePose();
  report.rms_m = 0.004;
  report.iterations = 23;
  report.method = "arref-icp";
  report.stages_run = {"crop", "icp"};
  report.timings = {{"crop", 1.5}, {"icp", 20.0}};
  const ResultHeader header{.request_id = 5, .robot_id = "kr5", .session_id = 3, .queue_ms = 2.0, .server_ms = 30.0};
  for (FrameConvention f : {FrameConvention::kUnity, FrameConvention::kRos}) {
    const pb::ServerMessage m = ResultMessage(header, report, Status::Ok(), f);
    ASSERT_TRUE(m.has_result());
    const pb::Result& r = m.result();
    EXPECT_EQ(r.request_id(), 5u);
    EXPECT_EQ(r.robot_id(), "kr5");
    EXPECT_EQ(r.session_id(), 3u);
    EXPECT_DOUBLE_EQ(r.queue_ms(), 2.0);
    EXPECT_DOUBLE_EQ(r.server_ms(), 30.0);
    EXPECT_EQ(r.status(), pb::RESULT_STATUS_LOW_CONFIDENCE);
    EXPECT_EQ(r.message(), "margin below threshold");
    EXPECT_EQ(r.frame(), ToProto(f));
    auto pose = PoseFromProto(r.t_world_base(), f);
    ASSERT_TRUE(pose.ok());
    EXPECT_TRUE(pose->isApprox(SomePose(), 1e-12));
    auto internal = MatrixFromProto(r.t_world_base_internal());
    ASSERT_TRUE(internal.ok());
    EXPECT_TRUE(internal->isApprox(SomePose(), 0.0)) << "the internal matrix ignores the frame";
    EXPECT_DOUBLE_EQ(r.rms_m(), 0.004);
    EXPECT_EQ(static_cast<int>(r.iterations()), 23);
    EXPECT_EQ(r.method(), "arref-icp");
    ASSERT_EQ(r.stages_size(), 2);
    EXPECT_EQ(r.stages(1), "icp");
    ASSERT_EQ(r.timings_size(), 2);
    EXPECT_EQ(r.timings(0).stage(), "crop");
    EXPECT_DOUBLE_EQ(r.timings(1).ms(), 20.0);
  }
  report.status = ResultStatus::kFailed;
  const pb::Result failed = ResultMessage(header, report, Status::Ok(), FrameConvention::kUnity).result();
  EXPECT_EQ(failed.status(), pb::RESULT_STATUS_FAILED);
  EXPECT_EQ(failed.error_code(), pb::ERROR_CODE_REGISTRATION_FAILED);
}

TEST(WireConvert, ResultMessageWithoutAReport) {
  const ResultHeader header{.request_id = 9};
  const pb::Result cancelled =
      ResultMessage(header, std::nullopt, Status::Cancelled("cancelled while running"), FrameConvention::kUnity).result();
  EXPECT_EQ(cancelled.status(), pb::RESULT_STATUS_CANCELLED);
  EXPECT_EQ(cancelled.error_code(), pb::ERROR_CODE_CANCELLED);
  EXPECT_EQ(cancelled.message(), "cancelled while running");
  const pb::Result failed =
      ResultMessage(header, std::nullopt, Status::FailedPrecondition("crop is empty"), FrameConvention::kRos).result();
  EXPECT_EQ(failed.status(), pb::RESULT_STATUS_FAILED);
  EXPECT_EQ(failed.error_code(), pb::ERROR_CODE_REGISTRATION_FAILED);
  EXPECT_EQ(failed.message(), "crop is empty");
}

TEST(WireConvert, ErrorCodeForStatus) {
  EXPECT_EQ(ErrorCodeFor(Status::InvalidArgument("x")), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_EQ(ErrorCodeFor(Status::Cancelled("x")), pb::ERROR_CODE_CANCELLED);
  EXPECT_EQ(ErrorCodeFor(Status::ResourceExhausted("x")), pb::ERROR_CODE_LIMIT_EXCEEDED);
  EXPECT_EQ(ErrorCodeFor(Status::Internal("x")), pb::ERROR_CODE_INTERNAL);
  EXPECT_EQ(ErrorCodeFor(Status::FailedPrecondition("x")), pb::ERROR_CODE_REGISTRATION_FAILED);
}

TEST(WireConvert, JointsFromProto) {
  pb::JointState m;
  m.add_names("a");
  m.add_positions(0.5);
  m.add_names("b");
  m.add_positions(-1.0);
  auto joints = JointsFromProto(m);
  ASSERT_TRUE(joints.ok());
  EXPECT_EQ(*joints, (JointValues{{"a", 0.5}, {"b", -1.0}}));
  m.add_names("c");
  EXPECT_FALSE(JointsFromProto(m).ok());
  m.add_positions(std::numeric_limits<double>::quiet_NaN());
  auto nan = JointsFromProto(m);
  ASSERT_FALSE(nan.ok());
  EXPECT_NE(nan.status().message().find("'c'"), std::string::npos);
}

TEST(WireConvert, SharedFrameIsTheEncodedFrame) {
  pb::ServerMessage m;
  m.mutable_pong()->set_nonce(3);
  EXPECT_EQ(*SharedFrame(m), EncodeFrame(m));
}

// The winding rule of arref.proto, checked on one triangle facing a viewer 1 m in front of it:
// clockwise as the viewer sees it in Unity (Unity's Mesh.triangles), counter-clockwise in ROS,
// both become the same outward normal; a counter-clockwise Unity triangle faces away.
TEST(WireConvert, TriangleWindingRuleOfTheProtocol) {
  const auto normal_toward_viewer = [](const pb::SurfaceUpsert& m, const Vec3& viewer_ros) {
    auto s = SurfaceFromProto(m);
    EXPECT_TRUE(s.ok()) << s.status().ToString();
    const auto& v = s->mesh.vertices;
    const auto& t = s->mesh.triangles.at(0);
    const Vec3 a = v[t[0]].cast<double>(), b = v[t[1]].cast<double>(), c = v[t[2]].cast<double>();
    return (b - a).cross(c - a).dot(viewer_ros - (a + b + c) / 3.0) > 0;  // right-handed normal
  };
  pb::SurfaceUpsert unity;
  unity.set_surface_id(1);
  unity.set_frame(pb::FRAME_CONVENTION_UNITY);
  *unity.mutable_t_world_surface() = PoseToProto(Iso3::Identity(), FrameConvention::kUnity);
  // In the plane z = 0; the viewer at Unity (0, 0, -1) looks along +z with x right and y up, and
  // sees (0,0,0) -> (0,1,0) -> (1,0,0) turn clockwise.
  for (float x : {0.f, 0.f, 0.f, 0.f, 1.f, 0.f, 1.f, 0.f, 0.f}) unity.add_vertices(x);
  for (std::uint32_t k : {0u, 1u, 2u}) unity.add_triangles(k);
  const Vec3 viewer = PositionToRos(Vec3(0, 0, -1), FrameConvention::kUnity);
  EXPECT_TRUE(normal_toward_viewer(unity, viewer)) << "clockwise in Unity faces the viewer";
  pb::SurfaceUpsert reversed = unity;
  reversed.set_triangles(1, 2);
  reversed.set_triangles(2, 1);
  EXPECT_FALSE(normal_toward_viewer(reversed, viewer)) << "counter-clockwise in Unity faces away: swap the 2nd and 3rd";
  // The same triangle sent in ROS: counter-clockwise as the viewer at ROS (-1, 0, 0) sees it.
  pb::SurfaceUpsert ros;
  ros.set_surface_id(1);
  ros.set_frame(pb::FRAME_CONVENTION_ROS);
  *ros.mutable_t_world_surface() = PoseToProto(Iso3::Identity(), FrameConvention::kRos);
  for (int k = 0; k < 3; ++k) {
    const Vec3 p = PositionToRos(Vec3(unity.vertices(3 * k), unity.vertices(3 * k + 1), unity.vertices(3 * k + 2)),
                                 FrameConvention::kUnity);
    for (int d = 0; d < 3; ++d) ros.add_vertices(static_cast<float>(p[d]));
  }
  for (std::uint32_t k : {0u, 2u, 1u}) ros.add_triangles(k);
  EXPECT_TRUE(normal_toward_viewer(ros, viewer)) << "counter-clockwise in ROS faces the viewer";
}

}  // namespace
}  // namespace arref::wire
