// Global methods on clean data: the robot's own surface, moved far from the seed. Every
// global method must find it without help from the seed's pose.
#include <gtest/gtest.h>
#include <spdlog/cfg/env.h>

#include <chrono>
#include <cmath>
#include <random>

#include "arref/scene/metrics.h"
#include "arref/pipeline/pipeline.h"
#include "arref/pipeline/registration.h"
#include "arref/baselines/baselines.h"
#include "arref/scene/sampling.h"
#include "robot_surface_scene.h"

namespace arref {
namespace {

using testing::MakeRobotSurfaceScene;
using testing::RobotSurfaceScene;

// A registry method run straight on the robot-surface scene, as the pipeline would call it.
Result<RegistrationOutput> RunMethod(Method method, const RobotSurfaceScene& c, const Iso3& seed,
                                     const RegistrationOptions& options) {
  const MethodInfo* info = FindMethod(method);
  if (!info) return Status::NotFound("method not built in");
  const TargetCloud target(c.scene_world);
  return info->run(MethodInput{.model_base = c.model_base,
                               .scene_world = c.scene_world,
                               .scene_target = target,
                               .T_world_seed = seed,
                               .options = options});
}

class GlobalMethods : public ::testing::TestWithParam<const char*> {};

TEST_P(GlobalMethods, FindTheRobotFarFromTheSeed) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  RegistrationOptions options;
  options.segmentation.enabled = false;  // nothing to segment: the scene is the robot
  options.super4pcs.max_time_s = 600.0;  // the bases decide, not the machine's load
  auto method = ParseMethod(GetParam());
  ASSERT_TRUE(method.ok());
  const Iso3 seed = c.T_world_base * MakeYawPose(0.3, 0.2, 0.0, 2.5);  // 0.36 m and 143 degrees off
  const auto t0 = std::chrono::steady_clock::now();
  auto out = RunMethod(*method, c, seed, options);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_TRUE(out.ok()) << out.status().ToString();
  const PoseError e = ComparePoses(out->T_world_base, c.T_world_base, c.model_base.points);
  RecordProperty("add_mm", std::to_string(e.add_m * 1e3));
  RecordProperty("seconds", std::to_string(s));
  EXPECT_LT(e.add_m, 0.01) << GetParam() << ": translation " << e.translation_m << " m, rotation " << e.rotation_deg
                           << " deg";
  ASSERT_GE(out->stages.size(), 2u);
  EXPECT_EQ(out->stages.front(), GetParam());
  EXPECT_EQ(out->stages.back(), "pcl-icp");
}

INSTANTIATE_TEST_SUITE_P(All, GlobalMethods, ::testing::Values("super4pcs", "fpfh-ransac"));

// The paper's failure case: the robot merged with another object (a table; here a big ball
// against its base, which plane removal cannot cut away) must be reported, not registered.
TEST(Segmentation, ReportsARobotTouchingAnotherObject) {
  spdlog::cfg::load_env_levels();
  ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  std::mt19937_64 rng(3);
  std::normal_distribution<double> gauss;
  // The ball's surface passes 1 cm behind the robot's rearmost point.
  Vec3 rear = Vec3::Zero();
  for (const auto& p : c.model_base.points)
    if (p.x() < rear.x()) rear = p.cast<double>();
  for (int i = 0; i < 30000; ++i) {
    const Vec3 on_sphere = Vec3(gauss(rng), gauss(rng), gauss(rng)).normalized();
    const Vec3 p_base = rear - Vec3(1.21, 0.0, 0.0) + 1.2 * on_sphere;
    c.scene_world.points.push_back((c.T_world_base * p_base).cast<float>());
    c.scene_world.normals.push_back((c.T_world_base.linear() * on_sphere).cast<float>());
  }
  RegistrationOptions options;
  auto out = RunMethod(Method::kSuper4pcs, c, c.T_world_base, options);
  ASSERT_FALSE(out.ok());
  EXPECT_EQ(out.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(out.status().message().find("touches other objects"), std::string::npos) << out.status().ToString();
}

TEST(Super4pcs, RejectsBadParameters) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  RegistrationOptions options;
  options.segmentation.enabled = false;
  options.super4pcs.overlap = 0;
  auto out = RunMethod(Method::kSuper4pcs, c, c.T_world_base, options);
  ASSERT_FALSE(out.ok());
  EXPECT_NE(out.status().message().find("overlap"), std::string::npos) << out.status().ToString();
}

TEST(Mls, SmoothsNoise) {
  // A 1x1 quad at z=0 and a 2x2 quad at z=1.
  TriangleMesh quads;
  quads.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {2, 0, 1}, {2, 2, 1}, {0, 2, 1}};
  quads.triangles = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}, {4, 6, 7}};
  PointCloud c = SampleSurface(quads, 5000, 1);
  std::mt19937_64 rng(2);
  std::normal_distribution<float> noise(0, 0.005f);
  for (auto& p : c.points) p.z() += noise(rng);
  auto smoothed = MlsResample(c, MlsOptions{.search_radius_m = 0.1});
  ASSERT_TRUE(smoothed.ok()) << smoothed.status().ToString();
  double before = 0, after = 0;
  for (const auto& p : c.points) before += std::pow(p.z() - std::round(p.z()), 2);
  for (const auto& p : smoothed->points) after += std::pow(p.z() - std::round(p.z()), 2);
  EXPECT_LT(std::sqrt(after / smoothed->size()), 0.5 * std::sqrt(before / c.size()));
  MlsOptions up{.search_radius_m = 0.1, .upsampling = MlsOptions::Upsampling::kSampleLocalPlane,
                .upsampling_radius_m = 0.03, .upsampling_step_m = 0.01};
  auto upsampled = MlsResample(c, up);
  ASSERT_TRUE(upsampled.ok());
  EXPECT_GT(upsampled->size(), c.size());
  EXPECT_FALSE(MlsResample(c, MlsOptions{.search_radius_m = -1}).ok());
}

}  // namespace
}  // namespace arref
