// arref's ICP kernel (fast_icp.h) on the robot's own surface at a known pose: both metrics,
// the 4-DoF subgroup, the robust kernel, the relative-cost stop, and the same result on any
// number of threads.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <random>
#include <span>
#include <stdexcept>

#include "arref/icp/fast_icp.h"
#include "arref/scene/metrics.h"
#include "arref/pipeline/pipeline.h"
#include "robot_surface_scene.h"

namespace arref {
namespace {

using testing::MakeRobotSurfaceScene;
using testing::RobotSurfaceScene;

void AddNoise(PointCloud& cloud, float sigma_m, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, sigma_m);
  for (Vec3f& p : cloud.points) p += Vec3f(noise(rng), noise(rng), noise(rng));
}

double AddOf(const IcpStats& st, const RobotSurfaceScene& c) {
  return ComparePoses(st.T_target_source, c.T_world_base, c.model_base.points).add_m;
}

// 2 cm and 4 degrees off about a tilted axis: a 6-DoF offset (over 3 cm ADD).
Iso3 SixDofStart(const RobotSurfaceScene& c) {
  Iso3 offset = Iso3::Identity();
  offset.linear() = Eigen::AngleAxisd(4 * std::numbers::pi / 180, Vec3(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  offset.translation() = Vec3(0.012, -0.01, 0.012);
  return c.T_world_base * offset;
}

const std::vector<double> kLevels = {0.08, 0.04, 0.02, 0.012};

TEST(FastIcp, BothMetricsRecoverASixDofOffset) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const TargetCloud target(c.scene_world);
  const double start_add = ComparePoses(SixDofStart(c), c.T_world_base, c.model_base.points).add_m;
  for (IcpMetric metric : {IcpMetric::kPointToPlane, IcpMetric::kPointToPoint}) {
    IcpSettings s;
    s.metric = metric;
    const IcpStats st = AlignCoarseToFine(c.model_base, target, SixDofStart(c), kLevels, s).value();
    const bool plane = metric == IcpMetric::kPointToPlane;
    SCOPED_TRACE(plane ? "point-to-plane" : "point-to-point");
    EXPECT_GT(start_add, 0.03);
    // Measured: 0.02 mm (point-to-plane), 0.5 mm (point-to-point: two samplings of a surface
    // never coincide, and each pair pulls a point towards the other's sample).
    EXPECT_LT(AddOf(st, c), plane ? 0.0005 : 0.0015);
    EXPECT_TRUE(st.converged);
    EXPECT_GT(st.correspondences, 1000u);  // measured: 2,200 of 6,000 within 1.2 cm of the 4,000 samples
  }
}

TEST(FastIcp, YawOnlyMovesXyzAndYawAlone) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const TargetCloud target(c.scene_world);
  IcpSettings s;
  s.yaw_only = true;
  // From a 4-DoF offset it reaches the upright truth ...
  const Iso3 start = c.T_world_base * MakeYawPose(0.03, -0.02, 0.01, 0.08);
  EXPECT_LT(AddOf(AlignCoarseToFine(c.model_base, target, start, kLevels, s).value(), c), 0.001);
  // ... and from a tilted start it keeps the tilt: gravity's axis does not move.
  const Iso3 tilted = SixDofStart(c);
  const IcpStats st = AlignCoarseToFine(c.model_base, target, tilted, kLevels, s).value();
  const Vec3 up_before = tilted.linear().transpose() * Vec3::UnitZ();
  const Vec3 up_after = st.T_target_source.linear().transpose() * Vec3::UnitZ();
  EXPECT_LT((up_before - up_after).norm(), 1e-9);
  EXPECT_GT(st.iterations, 3);  // it did move
}

// A second layer within the correspondence distance: least squares averages the two, the
// Geman-McClure kernel holds to the layer it starts on.
TEST(FastIcp, RobustKernelIgnoresClutter) {
  ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  // A ghost of the whole surface 8 mm off along x: a second layer, as a badly tracked pass
  // of the headset leaves one.
  const std::size_t robot_points = c.scene_world.size();
  for (std::size_t i = 0; i < robot_points; ++i) {
    c.scene_world.points.push_back(c.scene_world.points[i] + Vec3f(0.008f, 0, 0));
    c.scene_world.normals.push_back(c.scene_world.normals[i]);
  }
  const TargetCloud target(c.scene_world);
  IcpSettings robust;
  robust.max_correspondence_m = 0.03;
  robust.kernel_scale_m = 0.003;
  IcpSettings least_squares = robust;
  least_squares.kernel_scale_m = 100;  // a weight of 1 for every pair within reach
  const Iso3 start = c.T_world_base * MakeYawPose(0.003, 0.0, 0.0, 0.0);
  const double robust_add = AddOf(Align(c.model_base, target, start, robust), c);
  const double ls_add = AddOf(Align(c.model_base, target, start, least_squares), c);
  EXPECT_LT(robust_add, 0.0015);  // measured: 0.9 mm
  EXPECT_GT(ls_add, 0.0025);      // measured: 3.1 mm, between the layers
}

// The reduction is deterministic (oneTBB's parallel_deterministic_reduce over fixed blocks):
// one, two or eight threads give the same pose to the last bit.
TEST(FastIcp, SameResultOnAnyNumberOfThreads) {
  ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  AddNoise(c.scene_world, 0.004f, 7);
  const TargetCloud target(c.scene_world);
  for (IcpMetric metric : {IcpMetric::kPointToPlane, IcpMetric::kPointToPoint}) {
    IcpSettings s;
    s.metric = metric;
    std::vector<IcpStats> runs;
    for (std::size_t threads : {1, 2, 8}) {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
      runs.push_back(AlignCoarseToFine(c.model_base, target, SixDofStart(c), kLevels, s).value());
    }
    for (const IcpStats& run : runs) {
      EXPECT_TRUE(run.T_target_source.matrix() == runs.front().T_target_source.matrix());
      EXPECT_EQ(run.iterations, runs.front().iterations);
    }
  }
}

// Nothing within reach: the start is returned untouched, not converged.
TEST(FastIcp, NoPairsKeepTheStart) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const TargetCloud target(c.scene_world);
  const Iso3 far = MakeYawPose(20, 0, 0, 0) * c.T_world_base;
  for (IcpMetric metric : {IcpMetric::kPointToPlane, IcpMetric::kPointToPoint}) {
    IcpSettings s;
    s.metric = metric;
    const IcpStats st = Align(c.model_base, target, far, s);
    EXPECT_TRUE(st.T_target_source.matrix() == far.matrix());
    EXPECT_FALSE(st.converged);
    EXPECT_EQ(st.correspondences, 0u);
  }
}

// The relative-cost stop (IcpSettings::converged_cost_ratio, Besl & McKay's tau) on a noisy
// scene, where the last iterations crawl: it must end the levels sooner and leave the fit as
// close to the truth as running them out does.
TEST(FastIcp, CostRatioStopsTheCrawlNotTheFit) {
  ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  AddNoise(c.scene_world, 0.004f, 5);  // a headset's few millimetres
  const TargetCloud target(c.scene_world);
  const Iso3 start = MakeYawPose(0.03, -0.02, 0.01, 0.05) * c.T_world_base;
  IcpSettings stop;
  stop.yaw_only = true;
  stop.max_iterations = 30;
  IcpSettings run_out = stop;
  run_out.converged_cost_ratio = 0;
  const IcpStats a = AlignCoarseToFine(c.model_base, target, start, kLevels, stop).value();
  const IcpStats b = AlignCoarseToFine(c.model_base, target, start, kLevels, run_out).value();
  EXPECT_LT(a.iterations, b.iterations);  // measured: 12 against 13
  EXPECT_LT(AddOf(a, c), 0.003) << "with the stop";
  EXPECT_LT(AddOf(b, c), 0.003) << "run out";
  EXPECT_NEAR(AddOf(a, c), AddOf(b, c), 0.001);  // measured: 0.47 and 0.53 mm
}

// A bent scene: the samples of the robot's upper half moved 6 mm along x, as a badly tracked
// view moves what it alone saw. Per-point weights decide which half the fit follows.
TEST(FastIcp, WeightsDecideWhichPartOfABentSceneCounts) {
  ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  std::vector<float> z;
  for (const Vec3f& p : c.model_base.points) z.push_back(p.z());
  std::nth_element(z.begin(), z.begin() + static_cast<std::ptrdiff_t>(z.size() / 2), z.end());
  const float middle = z[z.size() / 2];
  const Iso3 T_base_world = c.T_world_base.inverse();
  for (Vec3f& p : c.scene_world.points)
    if ((T_base_world * p.cast<double>()).z() > middle) p += Vec3f(0.006f, 0, 0);
  const TargetCloud target(c.scene_world);
  std::vector<float> lower, upper;
  for (const Vec3f& p : c.model_base.points) {
    lower.push_back(p.z() > middle ? 1e-3f : 1.0f);
    upper.push_back(p.z() > middle ? 1.0f : 1e-3f);
  }
  IcpSettings s;
  s.yaw_only = true;
  const Iso3 start = c.T_world_base * MakeYawPose(0.01, -0.01, 0.005, 0.03);
  const auto shift = [&](std::span<const float> w) {
    const IcpStats st = AlignCoarseToFine(c.model_base, target, start, kLevels, s, w).value();
    return (st.T_target_source.translation() - c.T_world_base.translation()).x();
  };
  const double to_lower = shift(lower), to_upper = shift(upper), equal = shift({});
  EXPECT_NEAR(to_lower, 0.0, 0.001);    // measured: 0.01 mm
  EXPECT_NEAR(to_upper, 0.006, 0.001);  // measured: 6.02 mm
  // Equal weights: between the halves (measured: 0.93 mm; the robust kernel holds to the half
  // its start lies nearer).
  EXPECT_GT(equal, to_lower + 0.0005);
  EXPECT_LT(equal, to_upper - 0.0005);
  const auto mismatched = AlignCoarseToFine(c.model_base, target, start, kLevels, s, std::span<const float>(lower).first(10));
  EXPECT_EQ(mismatched.status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace arref
