// RegisterRequest -> Job without a socket: a good request yields a job with the request's
// options; each bad field is refused with an error that names it, mapped to its wire code.
#include <gtest/gtest.h>

#include <cmath>

#include <map>
#include <string>

#include "arref/base/frames.h"
#include "request_builder.h"
#include "server_config.h"

namespace arref::server {
namespace {

namespace pb = wire::pb;

class RequestBuilder : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto config = ParseServerConfig("robots: [{id: kr5, urdf: builtin}]\n", "/tmp");
    ASSERT_TRUE(config.ok()) << config.status().ToString();
    config_ = new ServerConfig(std::move(*config));
    auto robots = RobotRegistry::Load(config_->robots, 4);
    ASSERT_TRUE(robots.ok()) << robots.status().ToString();
    robots_ = robots->release();
  }
  static void TearDownTestSuite() {
    delete robots_;
    delete config_;
  }

  static Iso3 SomePose() {
    Iso3 T = Iso3::Identity();
    T.translate(Vec3(0.5, -1.0, 0.25));
    T.rotate(Eigen::AngleAxisd(0.3, Vec3(0, 0, 1).normalized()));
    return T;
  }
  static pb::RegisterRequest GoodRequest() {
    pb::RegisterRequest m;
    m.set_request_id(17);
    m.set_robot_id("kr5");
    *m.mutable_seed()->mutable_t_world_seed() = wire::PoseToProto(SomePose(), FrameConvention::kUnity);
    m.mutable_seed()->set_frame(pb::FRAME_CONVENTION_UNITY);
    return m;
  }
  Result<std::shared_ptr<Job>> Build(const pb::RegisterRequest& m) const {
    return BuildJob(m, *robots_, config_->registration, session_);
  }
  // Builds, expects a refusal with the given wire code and a message containing `names`.
  void ExpectRefused(const pb::RegisterRequest& m, pb::ErrorCode code, const std::string& names) const {
    auto job = Build(m);
    ASSERT_FALSE(job.ok()) << "accepted, expected an error naming " << names;
    EXPECT_EQ(RequestErrorCode(job.status()), code) << job.status().ToString();
    EXPECT_NE(job.status().message().find(names), std::string::npos) << job.status().message();
  }

  static ServerConfig* config_;
  static RobotRegistry* robots_;
  std::map<std::string, SessionJoints> session_joints_;
  SessionDefaults session_{.seed = std::nullopt, .seed_frame = FrameConvention::kUnity, .joints = &session_joints_};
};

ServerConfig* RequestBuilder::config_ = nullptr;
RobotRegistry* RequestBuilder::robots_ = nullptr;

TEST_F(RequestBuilder, GoodRequestBecomesAJobWithItsOptions) {
  pb::RegisterRequest m = GoodRequest();
  const Method other = config_->registration.method == Method::kPclIcp ? Method::kArrefIcpFast : Method::kPclIcp;
  m.set_method(MethodName(other));
  m.mutable_params()->set_crop_radius_m(1.5);
  m.mutable_params()->set_scene_samples(5000);
  m.mutable_params()->set_icp_max_correspondence_m(0.02);
  m.mutable_params()->set_icp_max_iterations(12);
  m.mutable_joints()->add_names("joint_a2");
  m.mutable_joints()->add_positions(-0.5);
  m.set_result_frame(pb::FRAME_CONVENTION_ROS);
  // Internal positions sent as Unity ones.
  *m.mutable_head_path() = wire::HeadPathToProto({Vec3(0, 0, 1.6), Vec3(0.1, 0, 1.6)}, FrameConvention::kUnity);
  ASSERT_NE(m.head_path().positions(1).x(), 0.1) << "Unity's axes differ from the internal ones";

  auto job = Build(m);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  const Job& j = **job;
  EXPECT_EQ(j.request_id, 17u);
  EXPECT_EQ(j.robot_id, "kr5");
  EXPECT_TRUE(j.T_world_seed.isApprox(SomePose(), 1e-9));
  EXPECT_EQ(j.result_frame, FrameConvention::kRos);
  EXPECT_EQ(j.options.method, other);
  EXPECT_DOUBLE_EQ(j.options.crop_radius_m, 1.5);
  EXPECT_EQ(j.options.scene_samples, 5000u);
  EXPECT_DOUBLE_EQ(j.options.icp.max_correspondence_m, 0.02);
  EXPECT_EQ(j.options.icp.max_iterations, 12);
  ASSERT_EQ(j.options.head_path_world.size(), 2u);
  EXPECT_TRUE(j.options.head_path_world[1].isApprox(Vec3(0.1, 0, 1.6))) << "back in the internal frame";
  EXPECT_DOUBLE_EQ(j.joints.at("joint_a2"), -0.5);
  const ServedRobot& robot = *robots_->Find("kr5");
  for (const auto& joint : robot.model.ActuatedJoints()) EXPECT_TRUE(j.joints.count(joint.name)) << joint.name;
  EXPECT_FALSE(Cancelled(&j.cancel));
}

TEST_F(RequestBuilder, UnsetFieldsFallBackToConfigAndSession) {
  pb::RegisterRequest m;
  m.set_request_id(1);
  m.set_robot_id("kr5");
  session_.seed = SomePose();
  session_.seed_frame = FrameConvention::kRos;
  session_joints_[""].values = {{"joint_a2", -0.4}};
  auto job = Build(m);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  EXPECT_TRUE((*job)->T_world_seed.isApprox(SomePose()));
  EXPECT_EQ((*job)->result_frame, FrameConvention::kRos) << "results come in the seed's frame";
  EXPECT_EQ((*job)->options.method, config_->registration.method);
  EXPECT_DOUBLE_EQ((*job)->options.crop_radius_m, config_->registration.crop_radius_m);
  EXPECT_DOUBLE_EQ((*job)->joints.at("joint_a2"), -0.4);

  // A joint state sent for this robot wins over one sent for any robot.
  session_joints_["kr5"].values = {{"joint_a2", -0.3}};
  job = Build(m);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  EXPECT_DOUBLE_EQ((*job)->joints.at("joint_a2"), -0.3);
}

// A request never runs on joints the client did not mean: the latest JointState it would use
// was rejected, so it fails naming that rejection; its own joints, or a valid state, go on.
TEST_F(RequestBuilder, RejectedJointStateFailsTheRequestsThatWouldUseIt) {
  pb::RegisterRequest m;
  m.set_request_id(1);
  m.set_robot_id("kr5");
  session_.seed = SomePose();
  session_joints_["kr5"].rejected = "joint 'joint_nope' is not a joint of robot kr5";
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "latest JointState for robot 'kr5' was rejected (joint 'joint_nope'");
  // A rejected state for every robot ("") is used only where the robot has none of its own.
  session_joints_.clear();
  session_joints_[""].rejected = "joint state has 2 names but 1 positions";
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "2 names but 1 positions");
  session_joints_["kr5"].values = {{"joint_a2", -0.3}};
  auto job = Build(m);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  EXPECT_DOUBLE_EQ((*job)->joints.at("joint_a2"), -0.3);
  // The request's own joints win over a rejected session state.
  session_joints_["kr5"] = SessionJoints{.values = {}, .rejected = "position of joint_a1 is not finite"};
  m.mutable_joints()->add_names("joint_a2");
  m.mutable_joints()->add_positions(-0.2);
  job = Build(m);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  EXPECT_DOUBLE_EQ((*job)->joints.at("joint_a2"), -0.2);
}

TEST_F(RequestBuilder, OutOfRangeResultFrameIsRefused) {
  pb::RegisterRequest m = GoodRequest();
  m.set_result_frame(static_cast<pb::FrameConvention>(99));
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT,
                "RegisterRequest.result_frame: frame convention 99 is not one of UNITY (1) or ROS (2)");
  m.set_result_frame(pb::FRAME_CONVENTION_UNSPECIFIED);
  EXPECT_TRUE(Build(m).ok()) << "unset: the seed's frame";
  // Seeds (and so SeedPose, surfaces and head paths, through the same conversion) too.
  m.mutable_seed()->set_frame(static_cast<pb::FrameConvention>(-3));
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest.seed: frame convention -3 is not one of");
}

TEST_F(RequestBuilder, UnknownRobot) {
  pb::RegisterRequest m = GoodRequest();
  m.set_robot_id("r2d2");
  ExpectRefused(m, pb::ERROR_CODE_UNKNOWN_ROBOT, "robot 'r2d2' is not served here (served: kr5)");
}

TEST_F(RequestBuilder, NoSeedForAMethodThatNeedsOne) {
  pb::RegisterRequest m = GoodRequest();
  m.clear_seed();
  m.set_method("pcl-icp");
  ExpectRefused(m, pb::ERROR_CODE_NO_SEED, "no seed: method 'pcl-icp' needs one");
}

TEST_F(RequestBuilder, NoSeedAndNoMethodSearchesTheWholeMapWithTheHints) {
  pb::RegisterRequest m = GoodRequest();
  m.clear_seed();
  m.mutable_gaze_point()->set_x(1.0);  // Unity: x right, y up, z forward
  m.mutable_gaze_point()->set_y(0.5);
  m.mutable_gaze_point()->set_z(2.0);
  auto job = Build(m);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  EXPECT_TRUE((*job)->seedless);
  EXPECT_EQ((*job)->options.method, Method::kArrefAuto);
  ASSERT_TRUE((*job)->hint.gaze_point_world.has_value());
  EXPECT_TRUE((*job)->hint.gaze_point_world->isApprox(Vec3(2.0, -1.0, 0.5)));  // ROS: (z, -x, y)
  EXPECT_FALSE((*job)->hint.wearer_position_world.has_value());
  // A seedless method named, seed or not, searches the whole map too.
  pb::RegisterRequest seeded = GoodRequest();
  seeded.set_method("arref-auto");
  auto whole = Build(seeded);
  ASSERT_TRUE(whole.ok()) << whole.status().ToString();
  EXPECT_TRUE((*whole)->seedless);
  m.mutable_wearer_position()->set_x(std::nan(""));
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "wearer_position is not finite");
}

TEST_F(RequestBuilder, BadSeed) {
  pb::RegisterRequest m = GoodRequest();
  m.mutable_seed()->set_frame(pb::FRAME_CONVENTION_UNSPECIFIED);
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest.seed: frame convention not set");
  m = GoodRequest();
  m.mutable_seed()->mutable_t_world_seed()->clear_orientation();
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest.seed: pose needs both");
  m = GoodRequest();
  m.mutable_seed()->mutable_t_world_seed()->mutable_position()->set_x(std::numeric_limits<double>::quiet_NaN());
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest.seed: pose has non-finite values");
}

TEST_F(RequestBuilder, BadJoints) {
  pb::RegisterRequest m = GoodRequest();
  m.mutable_joints()->add_names("joint_a2");
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest.joints: joint state has 1 names but 0 positions");
  m.mutable_joints()->add_positions(std::numeric_limits<double>::infinity());
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest.joints: joint 'joint_a2' position is not finite");
  m = GoodRequest();
  m.mutable_joints()->add_names("no_such_joint");
  m.mutable_joints()->add_positions(0.0);
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "joints: ");
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "no_such_joint");
}

TEST_F(RequestBuilder, BadMethod) {
  pb::RegisterRequest m = GoodRequest();
  m.set_method("telepathy");
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest.method");
}

TEST_F(RequestBuilder, EachParamOutOfRangeIsNamed) {
  struct Case {
    void (*set)(pb::RegistrationParams*);
    std::string field;
  };
  const Case cases[] = {
      {[](pb::RegistrationParams* p) { p->set_crop_radius_m(0.0); }, "params.crop_radius_m = 0 is outside [0.01, 50]"},
      {[](pb::RegistrationParams* p) { p->set_crop_radius_m(std::nan("")); }, "params.crop_radius_m"},
      {[](pb::RegistrationParams* p) { p->set_scene_samples(2); }, "params.scene_samples = 2 is outside [3, 2000000]"},
      {[](pb::RegistrationParams* p) { p->set_icp_max_correspondence_m(20.0); }, "params.icp_max_correspondence_m"},
      {[](pb::RegistrationParams* p) { p->set_icp_max_iterations(0); }, "params.icp_max_iterations = 0"},
  };
  for (const Case& c : cases) {
    pb::RegisterRequest m = GoodRequest();
    c.set(m.mutable_params());
    ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, c.field);
  }
}

TEST_F(RequestBuilder, BadHeadPath) {
  pb::RegisterRequest m = GoodRequest();
  *m.mutable_head_path() = wire::HeadPathToProto({Vec3(0, 0, 1)}, FrameConvention::kUnity);
  m.mutable_head_path()->set_frame(pb::FRAME_CONVENTION_UNSPECIFIED);
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "RegisterRequest: head_path.frame");
  m = GoodRequest();
  *m.mutable_head_path() = wire::HeadPathToProto({Vec3(0, 0, 1), Vec3(0, 0, 1)}, FrameConvention::kUnity);
  m.mutable_head_path()->mutable_positions(1)->set_y(std::numeric_limits<double>::infinity());
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "head_path.positions[1] is not finite");
  m = GoodRequest();
  *m.mutable_head_path() =
      wire::HeadPathToProto(std::vector<Vec3>(kMaxHeadPathPositions + 1, Vec3(0, 0, 1)), FrameConvention::kUnity);
  ExpectRefused(m, pb::ERROR_CODE_INVALID_ARGUMENT, "at most 10000 allowed");
}

TEST_F(RequestBuilder, SeedIsCheckedBeforeJointsAndOptions) {
  pb::RegisterRequest m = GoodRequest();
  m.clear_seed();
  m.set_method("telepathy");
  m.mutable_joints()->add_names("joint_a2");
  ExpectRefused(m, pb::ERROR_CODE_NO_SEED, "no seed");
}

}  // namespace
}  // namespace arref::server
