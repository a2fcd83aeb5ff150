// The expected error of a fit (fit_precision.h) on the robot's own surface at a known pose: the
// fit's part follows the scene's noise, the map's follows the error per view and the eyes, and
// a scene that cannot pin the pose says so instead of giving a figure.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <random>
#include <vector>

#include "arref/icp/fit_precision.h"
#include "robot_surface_scene.h"

namespace arref {
namespace {

using testing::MakeRobotSurfaceScene;
using testing::RobotSurfaceScene;

// The scene's points moved along their normals by Gaussian noise of sigma_m.
PointCloud Noisy(const PointCloud& scene, float sigma_m, unsigned seed) {
  PointCloud out = scene;
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, sigma_m);
  for (std::size_t i = 0; i < out.points.size(); ++i) out.points[i] += noise(rng) * out.normals[i];
  return out;
}

// Eyes on a circle of 2 m round the base, 1.6 m up, over the given arc (degrees).
std::vector<Vec3> EyesRound(const Iso3& T_world_base, int count, double arc_deg) {
  std::vector<Vec3> eyes;
  for (int k = 0; k < count; ++k) {
    const double a = (arc_deg * k / count) * std::numbers::pi / 180.0;
    eyes.push_back(T_world_base * Vec3(2.0 * std::cos(a), 2.0 * std::sin(a), 1.6));
  }
  return eyes;
}

FitPrecision At(const RobotSurfaceScene& c, const PointCloud& scene, std::span<const Vec3> eyes,
                const PrecisionSettings& s = {}) {
  const TargetCloud target(scene);
  return MeasurePrecision(c.model_base.points, c.model_base.normals, target, c.T_world_base, eyes, nullptr, s);
}

TEST(FitPrecision, TheFitsPartFollowsTheNoiseOfTheScene) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const FitPrecision clean = At(c, c.scene_world, {});
  const FitPrecision one = At(c, Noisy(c.scene_world, 0.001f, 1), {});
  const FitPrecision four = At(c, Noisy(c.scene_world, 0.004f, 1), {});
  ASSERT_TRUE(clean.valid && one.valid && four.valid);
  EXPECT_GT(one.pairs, 3000u);
  // Two samplings of one surface differ along its normals too (measured: 1.8 mm RMS, most of it
  // at edges and on curved links), and the noise adds to that (2.1 and 4.1 mm).
  EXPECT_LT(clean.residual_rms_m, one.residual_rms_m);
  EXPECT_LT(one.residual_rms_m, four.residual_rms_m);
  EXPECT_NEAR(four.residual_rms_m, std::hypot(clean.residual_rms_m, 0.004), 0.0005);
  // The fit's error is in proportion to the residuals' scale (the pairs barely change).
  EXPECT_NEAR(four.fit_error_m / one.fit_error_m, four.residual_rms_m / one.residual_rms_m, 0.1);
  // Thousands of pairs pin the pose to a fraction of a millimetre (measured: 0.24 mm at 4 mm).
  EXPECT_LT(four.fit_error_m, 0.001);
  // With no eyes there is no map part, and the total is the fit's.
  EXPECT_EQ(four.map_error_m, 0.0);
  EXPECT_DOUBLE_EQ(four.expected_error_m, four.fit_error_m);
}

TEST(FitPrecision, ResidualsOnOneFacetCountOnce) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const PointCloud scene = Noisy(c.scene_world, 0.002f, 2);
  const FitPrecision each = At(c, scene, {});
  const FitPrecision per_5cm = At(c, scene, {}, PrecisionSettings{.correlation_m = 0.05});
  ASSERT_TRUE(each.valid && per_5cm.valid);
  // Measured: 1,236 cells of 5 cm hold the 4,000 pairs.
  EXPECT_LT(per_5cm.independent_pairs, each.independent_pairs / 3);
  // sigma scales with sqrt(pairs / independent pairs).
  const double expected_ratio = std::sqrt(static_cast<double>(each.pairs) / per_5cm.independent_pairs);
  EXPECT_NEAR(per_5cm.fit_error_m / each.fit_error_m, expected_ratio, 1e-6 * expected_ratio);
}

TEST(FitPrecision, TheMapsPartFollowsTheErrorPerViewAndWhereTheViewsWere) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const std::vector<Vec3> round = EyesRound(c.T_world_base, 24, 360);
  const std::vector<Vec3> few = EyesRound(c.T_world_base, 3, 60);
  PrecisionSettings s;  // 4 mm and 0.3 degrees per view
  const FitPrecision all_round = At(c, c.scene_world, round, s);
  const FitPrecision from_three = At(c, c.scene_world, few, s);
  s.view_error.position_m *= 2, s.view_error.orientation_deg *= 2;
  const FitPrecision doubled = At(c, c.scene_world, round, s);
  ASSERT_TRUE(all_round.valid && from_three.valid && doubled.valid);
  // Linear in the error per view.
  EXPECT_NEAR(doubled.map_error_m / all_round.map_error_m, 2.0, 1e-9);
  // Many views average their errors; three from one side do not.
  EXPECT_GT(from_three.map_error_m, 2 * all_round.map_error_m);
  // Three views' errors move the robot by millimetres: a view's 0.3 degrees alone moves a
  // point 2 m away by 10 mm.
  EXPECT_GT(from_three.map_error_m, 0.002);
  EXPECT_LT(from_three.map_error_m, 0.012);
  // The parts add as variances.
  EXPECT_NEAR(all_round.expected_error_m * all_round.expected_error_m,
              all_round.fit_error_m * all_round.fit_error_m + all_round.map_error_m * all_round.map_error_m, 1e-12);
}

TEST(FitPrecision, TwoSurfaceModelsThatDisagreeAddHalfTheirDifference) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const TargetCloud target(c.scene_world);
  auto with_other = [&](const Iso3& T_other) {
    const OtherSurfaceFit other{.T_world_base = T_other};  // even chances
    return MeasurePrecision(c.model_base.points, c.model_base.normals, target, c.T_world_base, {}, &other, {});
  };
  // The other model's fit 12 mm away along x: the pose lies at either, so 6 mm either way.
  const FitPrecision shifted = with_other(c.T_world_base * MakeYawPose(0.012, 0.0, 0.0, 0.0));
  ASSERT_TRUE(shifted.valid);
  EXPECT_NEAR(shifted.surface_error_m, 0.006, 1e-9);
  EXPECT_NEAR(shifted.sigma_vertical_m() * shifted.sigma_vertical_m(),
              shifted.fit_covariance(2, 2), 1e-15);  // nothing vertical from it
  // Turned 1 degree about the base: each point moves by its radius times the angle, half of it.
  const FitPrecision turned = with_other(c.T_world_base * MakeYawPose(0.0, 0.0, 0.0, std::numbers::pi / 180));
  ASSERT_TRUE(turned.valid);
  EXPECT_NEAR(turned.surface_covariance(3, 3), std::pow(std::numbers::pi / 360, 2), 1e-12);
  EXPECT_GT(turned.surface_error_m, 0.001);
  // The same fit: no part; and the parts add as variances.
  EXPECT_EQ(with_other(c.T_world_base).surface_error_m, 0.0);
  EXPECT_NEAR(shifted.expected_error_m * shifted.expected_error_m,
              shifted.fit_error_m * shifted.fit_error_m + shifted.surface_error_m * shifted.surface_error_m, 1e-12);
}

// The other model's fit counts by its chance q of being the right one: q (1 - q) of its
// difference's square, so a model that explains the scene far worse adds little.
TEST(FitPrecision, TheOtherSurfaceModelCountsByItsChance) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const TargetCloud target(c.scene_world);
  auto with_chance = [&](double chance) {
    const OtherSurfaceFit other{.T_world_base = c.T_world_base * MakeYawPose(0.012, 0.0, 0.0, 0.0), .chance = chance};
    return MeasurePrecision(c.model_base.points, c.model_base.normals, target, c.T_world_base, {}, &other, {});
  };
  EXPECT_NEAR(with_chance(0.1).surface_error_m, 0.012 * 0.3, 1e-9);  // sqrt(0.1 * 0.9) = 0.3
  EXPECT_NEAR(with_chance(0.9).surface_error_m, 0.012 * 0.3, 1e-9);
  EXPECT_EQ(with_chance(0.0).surface_error_m, 0.0);
  EXPECT_NEAR(with_chance(0.5).surface_error_m, 0.006, 1e-9);
}

// The kept model's misfit m (its median plane distance from the scene) counts as a horizontal
// error of m beside the two fits' difference: a shell m off the mesh can hold the fit m off,
// however many residuals there are.
TEST(FitPrecision, TheKeptModelsMisfitCountsAsAHorizontalErrorOfItsSize) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  const TargetCloud target(c.scene_world);
  auto with = [&](double shift_m, double misfit_m) {
    const OtherSurfaceFit other{.T_world_base = c.T_world_base * MakeYawPose(shift_m, 0.0, 0.0, 0.0), .chance = 0.5,
                                .kept_misfit_m = misfit_m};
    return MeasurePrecision(c.model_base.points, c.model_base.normals, target, c.T_world_base, {}, &other, {});
  };
  const FitPrecision misfit = with(0.0, 0.007);
  ASSERT_TRUE(misfit.valid);
  EXPECT_NEAR(misfit.surface_error_m, 0.007, 1e-9);
  EXPECT_EQ(misfit.surface_misfit_m, 0.007);
  EXPECT_NEAR(misfit.surface_covariance(0, 0), 0.007 * 0.007 / 2, 1e-12);
  EXPECT_NEAR(misfit.surface_covariance(1, 1), 0.007 * 0.007 / 2, 1e-12);
  EXPECT_EQ(misfit.surface_covariance(2, 2), 0.0);  // the support sets the height
  EXPECT_EQ(misfit.surface_covariance(3, 3), 0.0);
  // Beside a 12 mm difference at even chances (6 mm), the two add as variances.
  EXPECT_NEAR(with(0.012, 0.007).surface_error_m, std::hypot(0.006, 0.007), 1e-9);
  EXPECT_EQ(with(0.0, 0.0).surface_error_m, 0.0);
  EXPECT_GT(misfit.expected_error_m, misfit.fit_error_m);
  // No model point near the scene (MedianPlaneDistance's infinity) is no misfit measured, not an
  // infinite figure.
  const FitPrecision unmeasured = with(0.0, std::numeric_limits<double>::infinity());
  EXPECT_EQ(unmeasured.surface_misfit_m, 0.0);
  EXPECT_EQ(unmeasured.surface_error_m, 0.0);
  EXPECT_TRUE(std::isfinite(unmeasured.expected_error_m));
}

TEST(FitPrecision, AFlatSceneCannotPinThePoseAndSaysSo) {
  // A floor patch fitted to a floor: height is pinned, x, y and yaw are not.
  PointCloud patch, floor;
  for (int i = -20; i <= 20; ++i)
    for (int j = -20; j <= 20; ++j) {
      patch.points.emplace_back(0.01f * i, 0.01f * j, 0.0f);
      floor.points.emplace_back(0.02f * i + 0.005f, 0.02f * j + 0.005f, 0.0f);
    }
  patch.normals.assign(patch.points.size(), Vec3f::UnitZ());
  floor.normals.assign(floor.points.size(), Vec3f::UnitZ());
  const TargetCloud target(floor);
  const FitPrecision p = MeasurePrecision(patch.points, patch.normals, target, Iso3::Identity(), {}, nullptr, {});
  EXPECT_GT(p.pairs, 1000u);
  EXPECT_FALSE(p.valid);
  EXPECT_EQ(p.expected_error_m, 0.0);
}

TEST(FitPrecision, NoSceneNearTheModelIsNoFigure) {
  const ASSERT_OK_AND_ASSIGN(RobotSurfaceScene c, MakeRobotSurfaceScene());
  PointCloud far = c.scene_world;
  far.Transform(MakeYawPose(5.0, 0.0, 0.0, 0.0));
  const FitPrecision p = At(c, far, {});
  EXPECT_EQ(p.pairs, 0u);
  EXPECT_FALSE(p.valid);
}

}  // namespace
}  // namespace arref
