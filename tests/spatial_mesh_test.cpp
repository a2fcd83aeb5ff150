#include <gtest/gtest.h>

#include <cmath>

#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/spatial_mesh.h"

namespace arref {
namespace {

Surface Quad(std::uint64_t id, float size = 1.0f) {
  Surface s;
  s.id = id;
  s.mesh.vertices = {{0, 0, 0}, {size, 0, 0}, {size, size, 0}, {0, size, 0}};
  s.mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  return s;
}

TEST(SpatialMesh, ValidSurfaceIsAccepted) {
  SpatialMesh map;
  EXPECT_TRUE(map.Upsert(Quad(1)).ok());
  EXPECT_EQ(map.size(), 1u);
}

TEST(SpatialMesh, NonFiniteVertexIsRejectedWithItsIndex) {
  Surface s = Quad(7);
  s.mesh.vertices[2].y() = std::nanf("");
  const Status st = ValidateSurface(s);
  EXPECT_EQ(st.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(st.message().find("surface 7"), std::string::npos);
  EXPECT_NE(st.message().find("vertex 2"), std::string::npos);
}

TEST(SpatialMesh, IndexOutOfRangeIsRejected) {
  Surface s = Quad(3);
  s.mesh.triangles[1][2] = 4;
  const Status st = ValidateSurface(s);
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message().find("triangle 1 uses vertex 4"), std::string::npos) << st.message();
}

TEST(SpatialMesh, EmptyDegenerateAndBadTransformAreRejected) {
  Surface empty;
  empty.id = 9;
  EXPECT_NE(ValidateSurface(empty).message().find("empty"), std::string::npos);
  Surface flat = Quad(4);
  for (auto& v : flat.mesh.vertices) v = Vec3f(1, 2, 3);
  EXPECT_NE(ValidateSurface(flat).message().find("degenerate"), std::string::npos);
  Surface scaled = Quad(5);
  scaled.T_world_surface.linear() *= 2.0;
  EXPECT_NE(ValidateSurface(scaled).message().find("rigid"), std::string::npos);
  Surface inf = Quad(6);
  inf.T_world_surface.translation().x() = INFINITY;
  EXPECT_NE(ValidateSurface(inf).message().find("not finite"), std::string::npos);
}

TEST(SpatialMesh, BadUpdateKeepsThePreviousSurface) {
  SpatialMesh map;
  ASSERT_TRUE(map.Upsert(Quad(1, 2.0f)).ok());
  Surface bad = Quad(1);
  bad.mesh.triangles[0][0] = 99;
  EXPECT_FALSE(map.Upsert(bad).ok());
  ASSERT_EQ(map.size(), 1u);
  EXPECT_NEAR(map.MergedWorld()->SurfaceArea(), 4.0, 1e-6) << "the old 2x2 surface is still there";
}

TEST(SpatialMesh, UpdateReplacesAndTransformApplies) {
  SpatialMesh map;
  ASSERT_TRUE(map.Upsert(Quad(1)).ok());
  Surface moved = Quad(1);
  moved.T_world_surface = MakeYawPose(10, 0, 1, M_PI / 2);
  ASSERT_TRUE(map.Upsert(moved).ok());
  ASSERT_TRUE(map.Upsert(Quad(2)).ok());
  EXPECT_EQ(map.size(), 2u);
  const TriangleMesh merged = *map.MergedWorld();
  EXPECT_EQ(merged.triangles.size(), 4u);
  const Aabb box = BoundsOf(merged.vertices);
  EXPECT_NEAR(box.max.x(), 10.0, 1e-5);
  EXPECT_NEAR(box.max.z(), 1.0, 1e-5);
  EXPECT_TRUE(map.Remove(1));
  EXPECT_FALSE(map.Remove(1));
  EXPECT_EQ(map.size(), 1u);
}

// Requests share one merged mesh while the map is unchanged; a change makes a new one and
// leaves the mesh a running request holds as it was.
TEST(SpatialMesh, MergedWorldIsSharedUntilTheMapChanges) {
  SpatialMesh map;
  ASSERT_TRUE(map.Upsert(Quad(1)).ok());
  const auto first = map.MergedWorld();
  EXPECT_EQ(map.MergedWorld(), first) << "an unchanged map is merged once";
  Surface bad = Quad(1);
  bad.mesh.triangles[0][0] = 99;
  ASSERT_FALSE(map.Upsert(bad).ok());
  EXPECT_EQ(map.MergedWorld(), first) << "a refused update changes nothing";
  ASSERT_TRUE(map.Upsert(Quad(2)).ok());
  const auto second = map.MergedWorld();
  EXPECT_NE(second, first);
  EXPECT_EQ(first->triangles.size(), 2u) << "the mesh taken before the update is left as it was";
  EXPECT_EQ(second->triangles.size(), 4u);
  EXPECT_FALSE(map.Remove(7));
  EXPECT_EQ(map.MergedWorld(), second) << "removing an unknown surface changes nothing";
  ASSERT_TRUE(map.Remove(1));
  EXPECT_EQ(map.MergedWorld()->triangles.size(), 2u);
}

TEST(SpatialMesh, CropKeepsTrianglesTouchingTheSphere) {
  TriangleMesh grid;
  for (int i = 0; i < 10; ++i) grid.Append(Quad(0).mesh, MakeYawPose(i, 0, 0, 0));
  const TriangleMesh cropped = CropToSphere(grid, Vec3(0, 0, 0), 2.5);
  // Quads at x = 0, 1, 2 have a vertex within 2.5 m.
  EXPECT_EQ(cropped.triangles.size(), 6u);
  EXPECT_NEAR(cropped.SurfaceArea(), 3.0, 1e-6);
  for (const auto& t : cropped.triangles)
    for (auto v : t) EXPECT_LT(v, cropped.vertices.size());
  EXPECT_TRUE(CropToSphere(grid, Vec3(100, 0, 0), 1.0).empty());
}

// Triangles are tested in parallel; the kept ones come out in the mesh's order, on its vertices.
TEST(SpatialMesh, KeepTrianglesKeepsOrderAndVertices) {
  TriangleMesh grid;
  for (int i = 0; i < 5000; ++i) grid.Append(Quad(0).mesh, MakeYawPose(i % 100, i / 100, 0, 0));
  const auto keep = [&](const Triangle& t) { return (t[0] / 4) % 3 == 0 || t[1] % 7 == 0; };
  std::vector<Triangle> expected;
  for (const Triangle& t : grid.triangles)
    if (keep(t)) expected.push_back(t);
  const TriangleMesh kept = KeepTriangles(grid, keep);
  EXPECT_EQ(kept.triangles, expected);
  EXPECT_GT(expected.size(), grid.triangles.size() / 4);
  EXPECT_LT(expected.size(), grid.triangles.size() / 2);
  EXPECT_EQ(kept.vertices, grid.vertices);
  EXPECT_TRUE(KeepTriangles(TriangleMesh{}, keep).empty());
}

// The part of a mesh round a fitted model: a triangle is kept when its centroid lies within
// the distance of a model point, whatever its vertices' distances.
TEST(SpatialMesh, TrianglesNearKeepsTheMeshRoundThePoints) {
  TriangleMesh grid;
  for (int i = 0; i < 10; ++i) grid.Append(Quad(0).mesh, MakeYawPose(i, 0, 0, 0));
  // Quad i's centroids lie at (i + 1/3, 2/3) and (i + 2/3, 1/3), 0.1 m below the points.
  const PointIndex points({{2.5f, 0.5f, 0.1f}, {3.5f, 0.5f, 0.1f}});
  const TriangleMesh near = TrianglesNear(grid, points, 0.3);
  EXPECT_EQ(near.triangles.size(), 4u);  // quads 2 and 3, both triangles
  EXPECT_NEAR(near.SurfaceArea(), 2.0, 1e-6);
  for (const auto& t : near.triangles) EXPECT_GE(grid.vertices[t[0]].x(), 2.0f - 1e-6f);
  EXPECT_EQ(near.vertices.size(), grid.vertices.size());  // the same vertices: indices stay valid
  EXPECT_EQ(TrianglesNear(grid, points, 0.1).triangles.size(), 0u);  // every centroid is farther
  EXPECT_TRUE(TrianglesNear(grid, PointIndex({}), 1.0).empty());
}

}  // namespace
}  // namespace arref
