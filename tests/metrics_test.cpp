#include <gtest/gtest.h>

#include <limits>
#include <random>

#include "arref/metrics.h"

namespace arref {
namespace {

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

}  // namespace
}  // namespace arref
