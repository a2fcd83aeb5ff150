// FindSupports: the heights of horizontal surfaces an upright robot can stand on.
#include <gtest/gtest.h>

#include "arref/scene/sampling.h"
#include "arref/scene/supports.h"

namespace arref {
namespace {

// A horizontal square of side `size` at height z centred on (cx, cy), facing up.
void AddSquare(TriangleMesh* m, double cx, double cy, double z, double size) {
  const auto base = static_cast<std::uint32_t>(m->vertices.size());
  const double h = size / 2;
  for (const auto& [dx, dy] : {std::pair{-h, -h}, {h, -h}, {h, h}, {-h, h}})
    m->vertices.push_back(Vec3(cx + dx, cy + dy, z).cast<float>());
  m->triangles.push_back({base, base + 1, base + 2});
  m->triangles.push_back({base, base + 2, base + 3});
}

TEST(Supports, FloorAndPedestalTopBySize) {
  TriangleMesh m;
  AddSquare(&m, 0, 0, -0.2, 4.0);   // the floor
  AddSquare(&m, 0.5, 0, 0.4, 0.6);  // a pedestal's top, 0.6 m above it
  const PointCloud cloud = SampleSurface(m, 20000, 3);
  SupportSearch search;
  search.centre = Vec3(0.3, 0, 0.2);
  search.radius_m = 1.0;
  const std::vector<Support> supports = FindSupports(cloud, search);
  ASSERT_EQ(supports.size(), 2u);
  EXPECT_NEAR(supports[0].z, -0.2, 0.01);  // the floor holds the most points near the axis
  EXPECT_NEAR(supports[1].z, 0.4, 0.01);
  EXPECT_GT(supports[0].points, supports[1].points);
}

TEST(Supports, OnlyUpFacingPointsNearTheAxisCount) {
  TriangleMesh m;
  AddSquare(&m, 5, 5, 0.7, 1.0);  // a table far from the axis
  const PointCloud far_away = SampleSurface(m, 5000, 1);
  SupportSearch search;  // centred at the origin, radius 1 m
  EXPECT_TRUE(FindSupports(far_away, search).empty());
  PointCloud down = SampleSurface(m, 5000, 1);
  for (auto& n : down.normals) n = -n;  // a ceiling faces down
  search.centre = Vec3(5, 5, 0);
  EXPECT_TRUE(FindSupports(down, search).empty());
  EXPECT_TRUE(FindSupports(PointCloud{}, search).empty());
}

}  // namespace
}  // namespace arref
