#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include <tbb/global_control.h>

#include "arref/base/split_mix.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/sampling.h"
#include "test_support.h"

namespace arref {
namespace {

// The simulators' cells and the bench's splits (development and held-back) are drawn through
// SplitMix64: any change to it would silently redraw every split. These are the reference
// generator's first outputs for the seed 1234567 (Vigna's splitmix64.c: the state advances by
// the golden gamma, then is mixed).
TEST(SplitMix64, GivesTheReferenceGeneratorsOutputs) {
  constexpr std::uint64_t kGamma = 0x9E3779B97F4A7C15ull;
  EXPECT_EQ(SplitMix64(1234567), 6457827717110365317ull);
  EXPECT_EQ(SplitMix64(1234567 + kGamma), 3203168211198807973ull);
  EXPECT_EQ(SplitMix64(1234567 + 2 * kGamma), 9817491932198370423ull);
}

TriangleMesh TwoQuads() {
  // A 1x1 quad at z=0 and a 2x2 quad at z=1: the second holds 4/5 of the area.
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {2, 0, 1}, {2, 2, 1}, {0, 2, 1}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}, {4, 6, 7}};
  return m;
}

TEST(Sampling, UniformByArea) {
  const PointCloud c = SampleSurface(TwoQuads(), 20000, 1);
  ASSERT_EQ(c.size(), 20000u);
  ASSERT_TRUE(c.has_normals());
  std::size_t upper = 0;
  double mean_x_low = 0;
  std::size_t low = 0;
  for (std::size_t i = 0; i < c.size(); ++i) {
    if (c.points[i].z() > 0.5) {
      ++upper;
    } else {
      mean_x_low += c.points[i].x();
      ++low;
    }
    EXPECT_NEAR(c.normals[i].z(), 1.0f, 1e-6);
  }
  // Binomial(20000, 0.8): sigma = 57 points, so 4 sigma is about 0.011.
  EXPECT_NEAR(static_cast<double>(upper) / c.size(), 0.8, 0.012);
  EXPECT_NEAR(mean_x_low / low, 0.5, 0.02) << "uniform within a triangle pair";
}

TEST(Sampling, DeterministicForASeed) {
  const PointCloud a = SampleSurface(TwoQuads(), 500, 42);
  const PointCloud b = SampleSurface(TwoQuads(), 500, 42);
  const PointCloud c = SampleSurface(TwoQuads(), 500, 43);
  EXPECT_EQ(a.points, b.points);
  EXPECT_NE(a.points, c.points);
  EXPECT_TRUE(SampleSurface(TriangleMesh{}, 100, 1).empty());
}

// Areas and points are computed in parallel; the draws are not: one thread or many, a seed
// gives the same cloud (the bench's cells and every request's scene samples rest on it).
TEST(Sampling, SameCloudOnAnyNumberOfThreads) {
  TriangleMesh mesh;  // a wavy 1 x 1 m sheet of 20,000 triangles of unequal areas
  const int n = 100;
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j <= n; ++j)
      mesh.vertices.emplace_back(i / float(n), j / float(n), 0.05f * std::sin(0.3f * i) * std::cos(0.2f * j));
  for (std::uint32_t i = 0; i < n; ++i)
    for (std::uint32_t j = 0; j < n; ++j) {
      const std::uint32_t a = i * (n + 1) + j, b = a + n + 1;
      mesh.triangles.push_back({a, b, b + 1});
      mesh.triangles.push_back({a, b + 1, a + 1});
    }
  ASSERT_GT(mesh.triangles.size(), 3 * 4096u) << "the area loop must split into several ranges";
  const PointCloud parallel = SampleSurface(mesh, 30000, 7);
  PointCloud serial;
  {
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    serial = SampleSurface(mesh, 30000, 7);
  }
  EXPECT_EQ(parallel.points, serial.points);
  EXPECT_EQ(parallel.normals, serial.normals);
}

// The triangle pick searches only the slice of the running sum its draw falls in; the answer
// must be upper_bound's over the whole sum, as in the plain algorithm below (Osada et al.), on
// a mesh with zero-area triangles and areas spanning six orders of magnitude.
TEST(Sampling, SameCloudAsThePlainAlgorithm) {
  TriangleMesh mesh;
  std::mt19937_64 shape(5);
  std::uniform_real_distribution<float> u(0, 1);
  for (std::uint32_t t = 0; t < 5000; ++t) {
    const float size = std::pow(10.0f, -3.0f * u(shape));
    const Vec3f a(u(shape), u(shape), u(shape));
    const Vec3f b = a + size * Vec3f(u(shape), u(shape), 0);
    const Vec3f c = t % 7 == 0 ? b : Vec3f(a + size * Vec3f(0, u(shape), u(shape)));  // every 7th degenerate
    mesh.vertices.insert(mesh.vertices.end(), {a, b, c});
    mesh.triangles.push_back({3 * t, 3 * t + 1, 3 * t + 2});
  }
  const std::size_t n = 20000;
  std::vector<double> cumulative;
  double total = 0;
  for (const auto& t : mesh.triangles) {
    const Vec3f cross = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    cumulative.push_back(total += 0.5 * cross.norm());
  }
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const PointCloud c = SampleSurface(mesh, n, 11);
  ASSERT_EQ(c.size(), n);
  for (std::size_t k = 0; k < n; ++k) {
    const double pick = uniform(rng) * total;
    const auto i = std::min<std::size_t>(
        static_cast<std::size_t>(std::upper_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin()),
        cumulative.size() - 1);
    const auto& t = mesh.triangles[i];
    const float s = static_cast<float>(std::sqrt(uniform(rng)));
    const float r2 = static_cast<float>(uniform(rng));
    const Vec3f p = (1 - s) * mesh.vertices[t[0]] + s * (1 - r2) * mesh.vertices[t[1]] + s * r2 * mesh.vertices[t[2]];
    ASSERT_EQ(c.points[k], p) << "sample " << k << " should lie on triangle " << i;
  }
}

TEST(Sampling, RobotSampleLiesOnItsSurface) {
  auto robot = RobotModel::Load(testing::BuiltinRobotUrdf());
  ASSERT_TRUE(robot.ok());
  const PointCloud c = SampleSurface(*robot->PosedMesh({}), 10000, 3);
  const Aabb box = BoundsOf(c.points);
  EXPECT_NEAR(box.min.z(), 0.0, 1e-3) << "the base stands on z = 0";
  EXPECT_GT(box.max.x(), 1.4);
}

TEST(Sampling, VoxelDownsampleOnePointPerCell) {
  TriangleMesh mesh = TwoQuads();
  mesh.Transform(MakeYawPose(0, 0, 0.05, 0));  // planes mid-cell: rounding cannot split cells in z
  const PointCloud c = SampleSurface(mesh, 20000, 1);
  const PointCloud d = VoxelDownsample(c, 0.1);
  // 10x10 cells on the small quad, 20x20 on the big one.
  EXPECT_EQ(d.size(), 500u);
  EXPECT_TRUE(d.has_normals());
}

}  // namespace
}  // namespace arref
