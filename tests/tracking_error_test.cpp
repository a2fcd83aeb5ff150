// Weights from the headset's tracking error (tracking_error.h): a point seen head-on keeps only
// the position error, one seen at a grazing angle also the orientation error's sideways move,
// and every independent view that saw a point divides its variance.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "arref/fusion/tracking_error.h"

namespace arref {
namespace {

// One point 2 m in front of an eye at the origin, its normal tilted `tilt_deg` from the eye.
PointCloud PointTilted(double tilt_deg) {
  const double t = tilt_deg * std::numbers::pi / 180;
  PointCloud cloud;
  cloud.points.push_back(Vec3f(0, 0, 2));
  cloud.normals.push_back(Vec3f(static_cast<float>(std::sin(t)), 0, static_cast<float>(-std::cos(t))));
  return cloud;
}

TEST(TrackingError, GrazingViewsWeighLessThanHeadOnOnes) {
  const TrackingError error;  // 4 mm, 0.3 degrees
  PointCloud cloud = PointTilted(0);
  const PointCloud tilted = PointTilted(60);
  cloud.points.push_back(tilted.points[0]);
  cloud.normals.push_back(tilted.normals[0]);
  const std::vector<float> w = TrackingErrorWeights(cloud, {Vec3::Zero()}, error);
  ASSERT_EQ(w.size(), 2u);
  EXPECT_NEAR(w[0], 1.0, 1e-6);  // head-on: the position error alone, the unit of weight
  // At 60 degrees the orientation error moves the surface by 2 m x sin 60 x 0.3 degrees along
  // its normal: variance 16 + 82.2 mm^2 against 16.
  const double rad = 0.3 * std::numbers::pi / 180;
  const double expected = 16e-6 / (16e-6 + std::pow(2 * std::sin(std::numbers::pi / 3) * rad, 2));
  EXPECT_NEAR(w[1], expected, 1e-4);
  EXPECT_LT(w[1], 0.2);
}

TEST(TrackingError, EveryViewThatSawAPointDividesItsVariance) {
  const PointCloud cloud = PointTilted(30);
  const float one = TrackingErrorWeights(cloud, {Vec3::Zero()}, {}).at(0);
  const float three = TrackingErrorWeights(cloud, {Vec3::Zero(), Vec3::Zero(), Vec3::Zero()}, {}).at(0);
  EXPECT_NEAR(three, 3 * one, 1e-5 * one);
  // An eye behind the surface did not see it and changes nothing.
  const float with_behind = TrackingErrorWeights(cloud, {Vec3::Zero(), Vec3(0, 0, 4)}, {}).at(0);
  EXPECT_EQ(with_behind, one);
}

TEST(TrackingError, APointNoEyeFacesGetsTheSmallestWeight) {
  PointCloud cloud = PointTilted(0);
  const PointCloud tilted = PointTilted(50);
  cloud.points.push_back(tilted.points[0]);
  cloud.normals.push_back(tilted.normals[0]);
  cloud.points.push_back(Vec3f(0, 0, 2));
  cloud.normals.push_back(Vec3f(0, 0, 1));  // facing away from the eye
  const std::vector<float> w = TrackingErrorWeights(cloud, {Vec3::Zero()}, {});
  ASSERT_EQ(w.size(), 3u);
  EXPECT_LT(w[1], w[0]);
  EXPECT_EQ(w[2], w[1]);
}

TEST(TrackingError, NoEyesOrNoPositionErrorMeanEqualWeights) {
  const PointCloud cloud = PointTilted(20);
  EXPECT_TRUE(TrackingErrorWeights(cloud, {}, {}).empty());
  EXPECT_TRUE(TrackingErrorWeights(cloud, {Vec3::Zero()}, {.position_m = 0.0, .orientation_deg = 0.3}).empty());
  PointCloud no_normals = cloud;
  no_normals.normals.clear();
  EXPECT_TRUE(TrackingErrorWeights(no_normals, {Vec3::Zero()}, {}).empty());
}

}  // namespace
}  // namespace arref
