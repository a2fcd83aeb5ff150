#include <gtest/gtest.h>

#include <array>
#include <limits>
#include <random>

#include "arref/base/stats.h"
#include "arref/scene/metrics.h"
#include "arref/scene/nearest_neighbor.h"

namespace arref {
namespace {

// The tables' quantiles interpolate between order statistics (definition 7), whatever the order.
TEST(Stats, QuantilesInterpolateBetweenOrderStatistics) {
  const std::vector<double> v = {40, 10, 30, 20};
  EXPECT_DOUBLE_EQ(Median(v), 25.0);  // between the two middle values, not either of them
  EXPECT_DOUBLE_EQ(Quantile(v, 0.0), 10.0);
  EXPECT_DOUBLE_EQ(Quantile(v, 1.0), 40.0);
  EXPECT_DOUBLE_EQ(Quantile(v, 0.95), 38.5);  // position 2.85: 30 + 0.85 * 10
  EXPECT_DOUBLE_EQ(Median({7}), 7.0);
  EXPECT_DOUBLE_EQ(Median({3, 1, 2}), 2.0);
  EXPECT_TRUE(std::isnan(Median({})));
}

TEST(Metrics, AddOfAPureTranslationIsItsLength) {
  const std::vector<Vec3f> pts = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  const PoseError e = ComparePoses(MakeYawPose(0.01, 0.02, 0, 0), Iso3::Identity(), pts);
  EXPECT_NEAR(e.add_m, std::hypot(0.01, 0.02), 1e-9);
  EXPECT_NEAR(e.translation_m, std::hypot(0.01, 0.02), 1e-12);
  EXPECT_NEAR(e.rotation_deg, 0.0, 1e-9);
}

TEST(Metrics, RotationErrorInDegrees) {
  const PoseError e = ComparePoses(MakeYawPose(0, 0, 0, 0.1), MakeYawPose(0, 0, 0, -0.05), {{2, 0, 0}});
  EXPECT_NEAR(e.rotation_deg, 0.15 * 180 / M_PI, 1e-9);
  EXPECT_NEAR(e.add_m, 2 * 2 * std::sin(0.075), 1e-9);
}

TEST(Metrics, FitAgainstAKnownScene) {
  std::vector<Vec3f> scene;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) scene.emplace_back(0.01f * i, 0.01f * j, 0.0f);
  const PointIndex index(scene);
  // Model points 3 mm above grid nodes: RMS 3 mm, all within a 5 mm threshold.
  std::vector<Vec3f> model = {{0.1f, 0.1f, 0.003f}, {0.5f, 0.2f, 0.003f}, {0.3f, 0.7f, 0.003f}};
  FitQuality fit = MeasureFit(model, Iso3::Identity(), index, 0.005);
  EXPECT_NEAR(fit.rms_m, 0.003, 1e-6);
  EXPECT_DOUBLE_EQ(fit.inlier_fraction, 1.0);
  fit = MeasureFit(model, MakeYawPose(0, 0, 0.1, 0), index, 0.005);
  EXPECT_NEAR(fit.rms_m, 0.103, 1e-5);
  EXPECT_DOUBLE_EQ(fit.inlier_fraction, 0.0);
}

TEST(NearestNeighbor, MatchesBruteForce) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Vec3f> pts(2000);
  for (auto& p : pts) p = Vec3f(u(rng), u(rng), u(rng));
  const PointIndex index(pts);
  for (int q = 0; q < 200; ++q) {
    const Vec3f query(u(rng), u(rng), u(rng));
    std::uint32_t best = 0;
    for (std::uint32_t i = 1; i < pts.size(); ++i)
      if ((pts[i] - query).squaredNorm() < (pts[best] - query).squaredNorm()) best = i;
    std::uint32_t got;
    float sq;
    ASSERT_TRUE(index.Nearest(query, &got, &sq));
    EXPECT_EQ(got, best);
    EXPECT_FLOAT_EQ(sq, (pts[best] - query).squaredNorm());
  }
  EXPECT_FALSE(PointIndex({}).Nearest(Vec3f::Zero(), nullptr, nullptr));
}

// AnyWithin stops at the first point inside the bound: its answer must still be whether the
// nearest point lies inside, for bounds round the nearest distance (both sides of it) too.
TEST(NearestNeighbor, AnyWithinAnswersAsTheNearestDoes) {
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Vec3f> pts(3000);
  for (auto& p : pts) p = Vec3f(u(rng), u(rng), 0.1f * u(rng));  // a slab, like a mapped surface
  const PointIndex index(pts);
  int inside = 0, outside = 0;
  for (int q = 0; q < 400; ++q) {
    const Vec3f query(1.2f * u(rng), 1.2f * u(rng), 0.3f * u(rng));
    float nearest_sq = std::numeric_limits<float>::max();
    for (const Vec3f& p : pts) nearest_sq = std::min(nearest_sq, (p - query).squaredNorm());
    for (float bound : {0.25f * nearest_sq, 0.999f * nearest_sq, 1.001f * nearest_sq, 4.0f * nearest_sq}) {
      std::uint32_t i;
      float sq;
      const bool expected = index.NearestWithin(query, bound, &i, &sq);
      EXPECT_EQ(expected, bound > nearest_sq) << "bound " << bound << ", nearest " << nearest_sq;
      EXPECT_EQ(index.AnyWithin(query, bound), expected) << "query " << q << ", bound " << bound;
      (expected ? inside : outside) += 1;
    }
  }
  EXPECT_GT(inside, 400);
  EXPECT_GT(outside, 400);
  EXPECT_FALSE(PointIndex({}).AnyWithin(Vec3f::Zero(), 1.0f));
}

// MovingNearest answers from the points it kept round a query's last position: walks of small
// and large steps, with the bounds of arref-icp's levels changing on the way, must get the tree's
// answer at every step, found or not.
TEST(NearestNeighbor, MovingNearestAnswersAsTheTreeDoes) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Vec3f> pts(20000);
  for (auto& p : pts) p = Vec3f(u(rng), u(rng), 0.002f * u(rng));  // a mapped floor, ~1.4 cm apart
  const PointIndex index(pts);
  const std::array<float, 5> steps_m = {0.0002f, 0.001f, 0.003f, 0.01f, 0.05f};
  const std::array<float, 4> bounds_m = {0.012f, 0.02f, 0.08f, 0.3f};
  int found = 0, missed = 0;
  for (int walk = 0; walk < 40; ++walk) {
    MovingNearest moving;
    Vec3f query(0.9f * u(rng), 0.9f * u(rng), 0.02f * u(rng));
    const float step = steps_m[walk % steps_m.size()];
    for (int call = 0; call < 60; ++call) {
      query += step * Vec3f(u(rng), u(rng), 0.3f * u(rng));
      const float bound = bounds_m[(call / 15 + walk) % bounds_m.size()];
      std::uint32_t want_i = 0, got_i = 0;
      float want_sq = 0, got_sq = 0;
      const bool want = index.NearestWithin(query, bound * bound, &want_i, &want_sq);
      ASSERT_EQ(moving.NearestWithin(index, query, bound * bound, &got_i, &got_sq), want)
          << "walk " << walk << ", call " << call;
      if (!want) {
        ++missed;
        continue;
      }
      ++found;
      ASSERT_EQ(got_i, want_i) << "walk " << walk << ", call " << call;
      ASSERT_EQ(got_sq, want_sq);
    }
  }
  EXPECT_GT(found, 1000);
  EXPECT_GT(missed, 100);
}

}  // namespace
}  // namespace arref
