#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <iostream>
#include <numbers>
#include <string>
#include <utility>

#include "arref/fusion/model_reconstruction.h"
#include "arref/pipeline/pipeline.h"
#include "arref/fusion/raycaster.h"
#include "arref/fusion/robot_side.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/sampling.h"
#include "arref/fusion/tsdf.h"
#include "arref/scene/nearest_neighbor.h"
#include "test_support.h"

namespace arref {
namespace {

constexpr double kVoxel = 0.035;  // the small configuration's headset voxel

// An axis-aligned box standing on z = 0, outward (counter-clockwise) winding.
TriangleMesh Box(float sx, float sy, float sz) {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i)
    m.vertices.push_back({(i & 1 ? 0.5f : -0.5f) * sx, (i & 2 ? 0.5f : -0.5f) * sy, (i & 4 ? 1.0f : 0.0f) * sz});
  m.triangles = {{0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6}, {0, 1, 5}, {0, 5, 4},
                 {2, 6, 7}, {2, 7, 3}, {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}};
  return m;
}

// Surface points whose normal faces along sign * x (within about 25 deg).
std::ptrdiff_t FacingX(const PointCloud& c, float sign) {
  return std::count_if(c.normals.begin(), c.normals.end(), [&](const Vec3f& n) { return sign * n.x() > 0.9f; });
}

// Signed distance to an axis-aligned box [-h, h] x [-h, h] x [0, z] (positive outside).
double BoxDistance(const Vec3f& p, double hx, double hy, double z) {
  const Eigen::Vector3d q(std::abs(p.x()) - hx, std::abs(p.y()) - hy, std::abs(p.z() - z / 2) - z / 2);
  const double outside = q.cwiseMax(0.0).norm();
  return outside > 0 ? outside : q.maxCoeff();
}

TEST(ExpectedSurface, HugsTheRobotAndLeavesTheFloorOut) {
  ReconstructionOptions o;
  o.voxel_m = kVoxel;
  auto cloud = ExpectedRobotSurface(Box(0.4f, 0.4f, 0.8f), o, 5000, 1);
  ASSERT_TRUE(cloud.ok()) << cloud.status().ToString();
  ASSERT_EQ(cloud->size(), 5000u);
  ASSERT_TRUE(cloud->has_normals());
  std::size_t top = 0, outward = 0, sides = 0;
  std::vector<double> side_distance;
  for (std::size_t i = 0; i < cloud->size(); ++i) {
    const Vec3f& p = cloud->points[i];
    const Vec3f& n = cloud->normals[i];
    // A fused shell strays from the surface by a fraction of a voxel, never by more than two.
    EXPECT_LT(std::abs(BoxDistance(p, 0.2, 0.2, 0.8)), 2 * kVoxel) << p.transpose();
    top += p.z() > 0.8 - kVoxel && n.z() > 0.9f;
    if (std::abs(n.z()) < 0.5f) {
      ++sides;
      outward += n.head<2>().dot(p.head<2>()) > 0;
      if (p.z() > 0.2 && p.z() < 0.6) side_distance.push_back(BoxDistance(p, 0.2, 0.2, 0.8));
    }
  }
  EXPECT_GT(top, 300u) << "the top face is seen from a walker's height";
  EXPECT_GT(sides, 2000u);
  EXPECT_GT(outward, sides * 95 / 100) << "normals face free space";
  // On flat faces the shell lies on the surface (TSDF with incidence correction).
  std::nth_element(side_distance.begin(), side_distance.begin() + side_distance.size() / 2, side_distance.end());
  EXPECT_LT(std::abs(side_distance[side_distance.size() / 2]), 0.005);
}

TEST(ExpectedSurface, OneSidedWalkLeavesTheFarSideOut) {
  ReconstructionOptions o;
  o.voxel_m = kVoxel;
  auto round = ExpectedRobotSurface(Box(0.4f, 0.4f, 0.8f), o, 4000, 1);
  o.arc_deg = 120, o.arc_center_deg = 0;  // walked in front of +x only
  auto front = ExpectedRobotSurface(Box(0.4f, 0.4f, 0.8f), o, 4000, 1);
  ASSERT_TRUE(round.ok() && front.ok());
  EXPECT_GT(FacingX(*round, -1), 400);  // a fifth of the side area faces -x
  EXPECT_LT(FacingX(*front, -1), 40);
}

TEST(ExpectedSurface, BadOptionsNameTheProblem) {
  ReconstructionOptions o;
  o.voxel_m = 0;
  auto r = ExpectedRobotSurface(Box(0.4f, 0.4f, 0.8f), o, 100, 1);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().ToString().find("voxel"), std::string::npos) << r.status().ToString();
  o.voxel_m = kVoxel, o.arc_deg = 0;
  r = ExpectedRobotSurface(Box(0.4f, 0.4f, 0.8f), o, 100, 1);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().ToString().find("arc"), std::string::npos) << r.status().ToString();
  o.arc_deg = 360;
  r = ExpectedRobotSurface(TriangleMesh{}, o, 100, 1);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().ToString().find("no geometry"), std::string::npos) << r.status().ToString();
}

// Surfaces made together share the eyes they have in common, and come out as each alone.
TEST(ExpectedSurface, MadeTogetherAsAlone) {
  auto maker = ExpectedSurfaceMaker::Create(Box(0.4f, 0.4f, 0.8f), 1);
  ASSERT_TRUE(maker.ok()) << maker.status().ToString();
  ReconstructionOptions round, front, left, bad;
  round.voxel_m = front.voxel_m = left.voxel_m = kVoxel;
  round.azimuths = 8;                                        // every 45 degrees
  front.arc_deg = 90, front.azimuths = 3;                    // -45, 0, 45: all three on round's
  left.arc_deg = 90, left.arc_center_deg = 90, left.azimuths = 5;  // 45 .. 135 by 22.5: three on round's
  bad.voxel_m = 0;
  const std::vector<ReconstructionOptions> options = {round, front, bad, left};
  const std::vector<Result<PointCloud>> together = maker->MakeMany(options, 2000);
  ASSERT_EQ(together.size(), options.size());
  ASSERT_FALSE(together[2].ok());
  EXPECT_NE(together[2].status().ToString().find("voxel"), std::string::npos) << together[2].status().ToString();
  for (std::size_t i : {0u, 1u, 3u}) {
    auto alone = maker->Make(options[i], 2000);
    ASSERT_TRUE(alone.ok() && together[i].ok()) << i;
    ASSERT_EQ(alone->size(), together[i]->size()) << i;
    EXPECT_EQ(alone->points, together[i]->points) << i;
    EXPECT_EQ(alone->normals, together[i]->normals) << i;
  }
  EXPECT_NE(together[1]->points, together[3]->points);
}

// The eyes of an arc as ExpectedSurfaceMaker places them, given one by one instead.
std::vector<std::array<double, 3>> EyesOfArc(const ReconstructionOptions& o) {
  std::vector<std::array<double, 3>> eyes;
  const double step = o.arc_deg / (o.azimuths - 1);
  for (int a = 0; a < o.azimuths; ++a) {
    double degrees = std::fmod(o.arc_center_deg - o.arc_deg / 2 + step * a, 360.0);
    if (degrees < 0) degrees += 360.0;
    const double azimuth = degrees * std::numbers::pi / 180;
    eyes.push_back({o.distance_m * std::cos(azimuth), o.distance_m * std::sin(azimuth), o.eye_height_m});
  }
  return eyes;
}

TEST(ExpectedSurface, GivenEyesReplaceTheArc) {
  auto maker = ExpectedSurfaceMaker::Create(Box(0.4f, 0.4f, 0.8f), 1);
  ASSERT_TRUE(maker.ok()) << maker.status().ToString();
  ReconstructionOptions arc;
  arc.voxel_m = kVoxel, arc.arc_deg = 120, arc.arc_center_deg = 0, arc.azimuths = 9;
  ReconstructionOptions given;
  given.voxel_m = kVoxel;
  given.eyes_base = EyesOfArc(arc);
  auto from_arc = maker->Make(arc, 3000);
  auto from_eyes = maker->Make(given, 3000);
  ASSERT_TRUE(from_arc.ok() && from_eyes.ok()) << from_eyes.status().ToString();
  EXPECT_EQ(from_arc->points, from_eyes->points) << "the same eyes, the same surface";
  // Eyes behind the robot (-x) see its back, not its front, whatever arc the options name.
  for (auto& eye : given.eyes_base) eye[0] = -eye[0];
  auto from_back = maker->Make(given, 3000);
  ASSERT_TRUE(from_back.ok()) << from_back.status().ToString();
  EXPECT_GT(FacingX(*from_arc, 1), 300);
  EXPECT_GT(FacingX(*from_arc, 1), 8 * FacingX(*from_arc, -1));
  EXPECT_GT(FacingX(*from_back, -1), 300);
  EXPECT_GT(FacingX(*from_back, -1), 8 * FacingX(*from_back, 1));
}

// A table top (0.04 m thick, 0.5 m high) between a walker on the +x side and a box robot.
TriangleMesh TableInFront() {
  TriangleMesh table = Box(0.75f, 1.2f, 0.04f);
  const Iso3 T_base_table(Eigen::Translation3d(0.7, 0, 0.46));  // 12.5 cm from the robot
  table.Transform(T_base_table);
  return table;
}

TEST(ExpectedSurface, ObjectsMappedRoundTheRobotHideWhatTheyHid) {
  const TriangleMesh robot = Box(0.4f, 0.4f, 0.8f);
  auto maker = ExpectedSurfaceMaker::Create(robot, 1);
  ASSERT_TRUE(maker.ok()) << maker.status().ToString();
  ReconstructionOptions o;
  o.voxel_m = kVoxel, o.arc_deg = 120, o.arc_center_deg = 0;  // walked in front of +x
  // The headset's world: the robot (as mapped) and the table, somewhere else and turned.
  const Iso3 T_world_base = MakeYawPose(2.0, -1.0, 0.3, 0.7);
  TriangleMesh scene_world = robot;
  scene_world.Append(TableInFront());
  scene_world.Transform(T_world_base);

  auto alone = maker->Make(o, 4000);
  auto in_context = maker->MakeInContext(o, 4000, scene_world, T_world_base, 0.05);
  ASSERT_TRUE(alone.ok() && in_context.ok()) << in_context.status().ToString();
  auto low_front = [](const PointCloud& c) {  // the front face below the table's line of sight
    std::size_t n = 0;
    for (std::size_t i = 0; i < c.size(); ++i) n += c.normals[i].x() > 0.9f && c.points[i].z() < 0.25f;
    return n;
  };
  EXPECT_GT(low_front(*alone), 150u);
  EXPECT_LT(low_front(*in_context), low_front(*alone) / 10) << "the table hides the low front face";
  // The table is not part of the robot. Fusion leaves a few phantom patches in the table's
  // shadow next to the robot (the headset's mesh has them too), so not every point hugs the box.
  std::size_t on_box = 0;
  for (const Vec3f& p : in_context->points) {
    on_box += std::abs(BoxDistance(p, 0.2, 0.2, 0.8)) < 2 * kVoxel;
    ASSERT_FALSE(p.x() > 0.325 + kVoxel && std::abs(p.z() - 0.48) < kVoxel) << "on the table top: " << p.transpose();
  }
  EXPECT_GT(on_box, in_context->size() * 95 / 100);
  // The robot's own mapped surface is no object: the top is still seen.
  const auto top = std::count_if(in_context->points.begin(), in_context->points.end(),
                                 [](const Vec3f& p) { return p.z() > 0.8 - kVoxel; });
  EXPECT_GT(top, 300);
}

// The refit traces the robot through its own caster, instanced in the objects' (RayCaster::Create
// with `also`): every pixel must come out as from one caster built over both meshes, range and
// incidence, whichever of the two it hits.
TEST(RayCaster, AnInstanceTracesAsOneSceneOfBoth) {
  const TriangleMesh robot = Box(0.4f, 0.4f, 0.8f);
  const TriangleMesh table = TableInFront();
  auto robot_caster = RayCaster::Create(robot);
  TriangleMesh both = robot;
  both.Append(table);
  auto one = RayCaster::Create(both);
  ASSERT_TRUE(robot_caster.ok() && one.ok());
  auto instanced = RayCaster::Create(table, RayCaster::Build::kForOneUse, *robot_caster);
  ASSERT_TRUE(instanced.ok()) << instanced.status().ToString();
  const PinholeCamera camera = PinholeCamera::FromFov(90, 80, 70);
  std::size_t robot_hits = 0, table_hits = 0;
  for (int eye = 0; eye < 6; ++eye) {
    const double azimuth = -0.6 + 0.25 * eye;
    const Iso3 T_scene_camera = LookAt(Vec3(1.9 * std::cos(azimuth), 1.9 * std::sin(azimuth), 1.2), Vec3(0, 0, 0.4));
    std::vector<float> want_incidence, got_incidence, robot_incidence;
    const RangeImage want = one->Render(camera, T_scene_camera, 8.0, &want_incidence);
    const RangeImage got = instanced->Render(camera, T_scene_camera, 8.0, &got_incidence);
    const RangeImage robot_only = robot_caster->Render(camera, T_scene_camera, 8.0, &robot_incidence);
    for (std::size_t i = 0; i < want.size(); ++i) {
      ASSERT_EQ(got[i], want[i]) << "eye " << eye << ", pixel " << i;
      ASSERT_EQ(got_incidence[i], want_incidence[i]) << "eye " << eye << ", pixel " << i;
      if (want[i] > 0) (want[i] == robot_only[i] ? robot_hits : table_hits) += 1;
    }
  }
  EXPECT_GT(robot_hits, 1000u);
  EXPECT_GT(table_hits, 1000u);
}

// Rays are traced in packets of 16 along a row (RayPacket): a row whose width is no multiple of
// 16 and a mask that leaves lanes empty must still give every traced pixel the range and incidence
// of its own ray, and leave the others empty. Here against a floor, where both are known exactly.
TEST(RayCaster, EveryTracedPixelMeetsTheFloorWhereItsRayDoes) {
  TriangleMesh floor;
  floor.vertices = {Vec3f(-20, -20, 0), Vec3f(20, -20, 0), Vec3f(20, 20, 0), Vec3f(-20, 20, 0)};
  floor.triangles = {{0, 1, 2}, {0, 2, 3}};
  auto caster = RayCaster::Create(floor);
  ASSERT_TRUE(caster.ok()) << caster.status().ToString();
  const PinholeCamera camera = PinholeCamera::FromFov(37, 29, 60);
  const Iso3 T_scene_camera = LookAt(Vec3(0.3, -0.2, 1.6), Vec3(2.0, 1.0, 0.0));
  PixelMask traced(static_cast<std::size_t>(camera.width) * camera.height);
  for (std::size_t i = 0; i < traced.size(); ++i) traced[i] = i % 3 != 1;
  std::vector<float> incidence;
  const RangeImage range = caster->Render(camera, T_scene_camera, 50.0, &incidence, &traced);
  std::size_t hits = 0;
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * camera.width + u;
      const Vec3 dir = T_scene_camera.linear() * camera.RayDirection(u, v);
      if (!traced[i] || dir.z() >= 0) {
        EXPECT_EQ(range[i], 0.0f) << "pixel " << u << ", " << v;
        continue;
      }
      const double t = -T_scene_camera.translation().z() / dir.z();
      EXPECT_NEAR(range[i], t, 1e-5 * t) << "pixel " << u << ", " << v;
      EXPECT_NEAR(incidence[i], -dir.z(), 1e-5) << "pixel " << u << ", " << v;
      ++hits;
    }
  EXPECT_GT(hits, traced.size() / 2);  // two thirds are traced, and the camera looks down
}

// A TSDF kept to the band round the robot's points, as the refit's (one pixel per voxel aside).
TsdfOptions BandRoundRobot(const std::vector<Vec3f>* robot) {
  TsdfOptions o;
  o.voxel_m = kVoxel, o.truncation_m = 3 * kVoxel, o.crop_center = Vec3(0, 0, 0.4), o.crop_radius_m = 2.0;
  o.near_points = robot, o.near_margin_m = o.truncation_m + 2 * kVoxel, o.single_precision = true;
  return o;
}

// got's mesh is want, vertex for vertex and triangle for triangle.
void ExpectSameMesh(const TriangleMesh& want, const TsdfVolume& got) {
  const TriangleMesh b = got.ExtractMesh();
  ASSERT_EQ(want.vertices.size(), b.vertices.size());
  for (std::size_t i = 0; i < want.vertices.size(); ++i) ASSERT_EQ(want.vertices[i], b.vertices[i]) << "vertex " << i;
  EXPECT_EQ(want.triangles, b.triangles);
}

// The refit traces only the pixels NearPixels marks; the claim is that no other pixel changes a
// voxel of a volume kept to the band round the robot. Fused with the other pixels blanked, the
// mesh must be the same, vertex for vertex. So must it be when the band's blocks are listed
// without the volume's help (BandBlocks then steps every pixel, not only those through blocks
// the volume has yet to allocate).
TEST(ExpectedSurface, PixelsOffTheBandChangeNothing) {
  TriangleMesh scene = Box(0.4f, 0.4f, 0.8f);
  scene.Append(TableInFront());
  TriangleMesh far_wall = Box(0.1f, 4.0f, 2.0f);  // behind the robot, seen round it
  far_wall.Transform(Iso3(Eigen::Translation3d(-2.5, 0, 0)));
  scene.Append(far_wall);
  auto caster = RayCaster::Create(scene);
  ASSERT_TRUE(caster.ok()) << caster.status().ToString();
  const std::vector<Vec3f> robot = SampleSurface(Box(0.4f, 0.4f, 0.8f), 20000, 1).points;
  const TsdfOptions o = BandRoundRobot(&robot);
  TsdfVolume all(o), masked(o), unaided(o);
  const PinholeCamera camera = PinholeCamera::FromFov(90, 80, 70);
  std::size_t skipped = 0, traced = 0;
  for (int eye = 0; eye < 8; ++eye) {
    const double azimuth = -0.8 + 0.2 * eye;
    const Iso3 T_scene_camera = LookAt(Vec3(1.9 * std::cos(azimuth), 1.9 * std::sin(azimuth), 1.6), Vec3(0, 0, 0.4));
    std::vector<float> incidence;
    const RangeImage range = caster->Render(camera, T_scene_camera, 8.0, &incidence);
    const PixelMask mask = masked.NearPixels(camera, T_scene_camera);
    std::vector<float> blank_incidence;
    const RangeImage blanked = caster->Render(camera, T_scene_camera, 8.0, &blank_incidence, &mask);
    for (std::size_t i = 0; i < mask.size(); ++i) {
      (mask[i] ? traced : skipped) += range[i] > 0;
      if (mask[i]) {
        ASSERT_EQ(blanked[i], range[i]) << "a traced pixel renders as without a mask";
      }
    }
    ASSERT_TRUE(all.Integrate(camera, T_scene_camera, range, incidence).ok());
    ASSERT_TRUE(masked.Integrate(camera, T_scene_camera, blanked, blank_incidence).ok());
    const auto band = TsdfVolume::BandBlocks(o, camera, T_scene_camera, range);
    ASSERT_TRUE(unaided.Integrate(camera, T_scene_camera, range, incidence, band).ok());
    ASSERT_EQ(all.block_count(), unaided.block_count()) << "eye " << eye << ": the volume's help missed a block";
  }
  EXPECT_GT(skipped, traced / 10) << "the far wall and the floor beside the robot are off the band";
  EXPECT_GT(traced, 1000u);
  const TriangleMesh a = all.ExtractMesh();
  EXPECT_GT(a.triangles.size(), 500u);
  for (const TsdfVolume* other : {&masked, &unaided}) {
    EXPECT_EQ(other->block_count(), all.block_count());
    ExpectSameMesh(a, *other);
  }
}

// VoxelRows is a superset of the voxels within its radius of the points, and not much more:
// every row it leaves out has no voxel within the radius, and every row it keeps has one within
// the radius and a voxel's diagonal (each point counts as the centre of its voxel).
TEST(VoxelRows, HoldEveryVoxelWithinTheRadiusAndLittleMore) {
  const double voxel = 0.03, radius = 0.12;
  std::vector<Vec3f> points = SampleSurface(Box(0.3f, 0.2f, 0.5f), 3000, 2).points;
  points.push_back(Vec3f(-0.9f, 0.7f, -0.35f));  // a lone point, in negative blocks
  const VoxelRows rows = VoxelRows::Of(points, voxel, radius);
  const PointIndex index(points);
  const int B = TsdfVolume::kBlock;
  std::size_t kept = 0, left = 0;
  for (int bz = -3; bz <= 3; ++bz)
    for (int by = -4; by <= 4; ++by)
      for (int bx = -5; bx <= 3; ++bx) {
        const std::uint64_t mask = rows.RowsOf(Eigen::Vector3i(bx, by, bz));
        for (int z = 0; z < B; ++z)
          for (int y = 0; y < B; ++y) {
            double nearest = 1e9;  // of the row's voxel centres
            for (int x = 0; x < B; ++x) {
              const Vec3f c = (Eigen::Vector3i(bx * B + x, by * B + y, bz * B + z).cast<double>() * voxel).cast<float>();
              std::uint32_t i;
              float sq;
              if (index.Nearest(c, &i, &sq)) nearest = std::min(nearest, std::sqrt(static_cast<double>(sq)));
            }
            const bool on = mask >> (y + B * z) & 1;
            (on ? kept : left) += 1;
            if (!on) {
              ASSERT_GT(nearest, radius) << "block " << bx << " " << by << " " << bz << " row " << y << " " << z;
            } else {
              ASSERT_LE(nearest, radius + std::sqrt(3.0) * voxel + 1e-6) << "a row kept far from every point";
            }
          }
      }
  EXPECT_GT(kept, 1000u);
  EXPECT_GT(left, kept) << "most of the region is beyond the radius";
  EXPECT_EQ(rows.RowsOf(Eigen::Vector3i(40, 0, 0)), 0u) << "a block beyond the points' bounds";
  EXPECT_EQ(VoxelRows::Of({}, voxel, radius).RowsOf(Eigen::Vector3i::Zero()), 0u);
}

// A volume kept to the band's voxels (near_voxels_only) fuses them as the whole blocks do: each
// of its vertices is one of the whole blocks' mesh, bit for bit, and so is each of theirs within
// the band (a vertex's cell then lies inside the rows kept). Only farther off, where other
// objects cross the blocks, does it mesh less; blocks with none of the band's voxels are not
// even allocated. Eyes all round the built-in robot and a vendor arm
// (when ../shared is there), with a table, a floor and a far wall.
TEST(ExpectedSurface, BandVoxelsFuseAsTheWholeBlocksDo) {
  std::vector<std::pair<std::string, RobotLoadOptions>> urdfs = {{testing::BuiltinRobotUrdf(), {}}};
  if (testing::HaveShared())
    urdfs.push_back({testing::SharedDir() + "/robots/motoman_mh5_support/urdf/mh5.urdf",
                     RobotLoadOptions{.package_path = {testing::SharedDir() + "/robots"}}});
  else
    std::cerr << "../shared/robots not found at " << testing::SharedDir() << ": the built-in robot only\n";
  for (const auto& [urdf, load] : urdfs) {
    auto robot_model = RobotModel::Load(urdf, load);
    ASSERT_TRUE(robot_model.ok()) << robot_model.status().ToString();
    auto posed = robot_model->PosedMesh({});
    ASSERT_TRUE(posed.ok()) << posed.status().ToString();
    TriangleMesh scene = *posed;
    TriangleMesh floor = Box(6.0f, 6.0f, 0.01f);
    floor.Transform(Iso3(Eigen::Translation3d(0, 0, -0.01)));
    TriangleMesh wall = Box(0.1f, 4.0f, 2.0f);
    wall.Transform(Iso3(Eigen::Translation3d(-1.2, 0, 0)));
    for (const TriangleMesh& m : {floor, TableInFront(), wall}) scene.Append(m);
    auto caster = RayCaster::Create(scene);
    ASSERT_TRUE(caster.ok()) << caster.status().ToString();
    const std::vector<Vec3f> robot = SampleSurface(*posed, 20000, 1).points;
    const Aabb box = BoundsOf(posed->vertices);
    TsdfOptions whole = BandRoundRobot(&robot);
    whole.crop_center = ((box.min + box.max) / 2).cast<double>();
    whole.crop_radius_m = 0.5 * (box.max - box.min).norm() + 2 * whole.truncation_m;
    TsdfOptions band = whole;
    band.near_voxels_only = true;
    TsdfVolume a(whole), b(band);
    const PinholeCamera camera = PinholeCamera::FromFov(120, 108, 75);
    for (int eye = 0; eye < 24; ++eye) {
      const double azimuth = 2 * std::numbers::pi * eye / 24;
      const Iso3 T = LookAt(Vec3(1.9 * std::cos(azimuth), 1.9 * std::sin(azimuth), 1.65), whole.crop_center);
      std::vector<float> incidence;
      const RangeImage range = caster->Render(camera, T, 8.0, &incidence);
      ASSERT_TRUE(a.Integrate(camera, T, range, incidence).ok());
      ASSERT_TRUE(b.Integrate(camera, T, range, incidence).ok());
    }
    EXPECT_LT(b.block_count(), a.block_count()) << urdf << ": blocks with no voxel in the band are left out";
    const TriangleMesh ma = a.ExtractMesh(), mb = b.ExtractMesh();
    const PointIndex in_a(ma.vertices), in_b(mb.vertices), near_robot(robot);
    for (const Vec3f& v : mb.vertices) {
      std::uint32_t i;
      float sq;
      ASSERT_TRUE(in_a.Nearest(v, &i, &sq) && sq == 0.0f) << urdf << ": a vertex the whole blocks lack " << v.transpose();
    }
    const float inside = static_cast<float>(whole.near_margin_m - whole.voxel_m);
    std::size_t in_band = 0;
    for (const Vec3f& v : ma.vertices) {
      if (!near_robot.AnyWithin(v, inside * inside)) continue;
      ++in_band;
      std::uint32_t i;
      float sq;
      ASSERT_TRUE(in_b.Nearest(v, &i, &sq) && sq == 0.0f) << urdf << ": a vertex of the band lost " << v.transpose();
    }
    EXPECT_GT(in_band, 500u) << urdf;
    EXPECT_LT(mb.vertices.size(), ma.vertices.size()) << urdf << ": the table and the wall cross blocks beyond the band";
  }
}

// IntegrateAll updates each block with all its images in one task; the voxels must take the
// same updates in the same order as one Integrate per image gives them, so the mesh is the same
// vertex for vertex, including blocks that only later eyes add.
TEST(ExpectedSurface, IntegrateAllFusesAsOneImageAtATime) {
  TriangleMesh scene = Box(0.4f, 0.4f, 0.8f);
  scene.Append(TableInFront());
  auto caster = RayCaster::Create(scene);
  ASSERT_TRUE(caster.ok()) << caster.status().ToString();
  const std::vector<Vec3f> robot = SampleSurface(Box(0.4f, 0.4f, 0.8f), 20000, 1).points;
  const TsdfOptions o = BandRoundRobot(&robot);
  const PinholeCamera camera = PinholeCamera::FromFov(90, 80, 70);
  std::vector<Iso3> eyes;
  std::vector<RangeImage> ranges(8);
  std::vector<std::vector<float>> incidences(8);
  TsdfVolume one_by_one(o), at_once(o);
  std::size_t blocks_after_first = 0;
  for (int eye = 0; eye < 8; ++eye) {
    const double azimuth = -1.4 + 0.4 * eye;  // round to the far side: later eyes add blocks
    eyes.push_back(LookAt(Vec3(1.9 * std::cos(azimuth), 1.9 * std::sin(azimuth), 1.6), Vec3(0, 0, 0.4)));
    ranges[eye] = caster->Render(camera, eyes.back(), 8.0, &incidences[eye]);
    ASSERT_TRUE(one_by_one.Integrate(camera, eyes.back(), ranges[eye], incidences[eye]).ok());
    if (eye == 0) blocks_after_first = one_by_one.block_count();
  }
  std::vector<TsdfVolume::Image> images;
  for (int eye = 0; eye < 8; ++eye) images.push_back({eyes[eye], &ranges[eye], &incidences[eye]});
  ASSERT_TRUE(at_once.IntegrateAll(camera, images).ok());
  EXPECT_GT(one_by_one.block_count(), blocks_after_first + 10) << "later eyes add blocks";
  ASSERT_EQ(at_once.block_count(), one_by_one.block_count());
  const TriangleMesh a = one_by_one.ExtractMesh();
  EXPECT_GT(a.triangles.size(), 500u);
  ExpectSameMesh(a, at_once);
  const std::vector<float> short_incidence(3, 1.0f);
  images.back().incidence = &short_incidence;
  const Status bad = TsdfVolume(o).IntegrateAll(camera, images);
  EXPECT_EQ(bad.code(), StatusCode::kInvalidArgument) << bad.ToString();
}

// The volume's help to BandBlocks steps a pixel only when [r - trunc, r + trunc] along its ray
// reaches the depths of a near block not yet allocated. Walls of every depth through the band,
// seen from two eyes: the helped search must allocate exactly the blocks that stepping every
// pixel finds, after each eye.
TEST(ExpectedSurface, BandSearchFindsEveryBlockItsRaysReach) {
  const std::vector<Vec3f> robot = SampleSurface(Box(0.4f, 0.4f, 0.8f), 20000, 1).points;
  const TsdfOptions o = BandRoundRobot(&robot);
  const PinholeCamera camera = PinholeCamera::FromFov(90, 80, 70);
  const Iso3 T_first = LookAt(Vec3(1.9, 0, 1.6), Vec3(0, 0, 0.4));
  const Iso3 T_second = LookAt(Vec3(0.3, 1.8, 1.2), Vec3(0, 0, 0.4));
  const std::vector<float> incidence(static_cast<std::size_t>(camera.width) * camera.height, 1.0f);
  std::size_t blocks_seen = 0;
  for (float depth = 1.2f; depth < 2.8f; depth += 0.011f) {
    TsdfVolume helped(o), unaided(o);
    for (const Iso3* T : {&T_first, &T_second}) {
      const RangeImage range(incidence.size(), T == &T_first ? depth : 3.6f - depth);
      ASSERT_TRUE(helped.Integrate(camera, *T, range, incidence).ok());
      ASSERT_TRUE(unaided.Integrate(camera, *T, range, incidence, TsdfVolume::BandBlocks(o, camera, *T, range)).ok());
      ASSERT_EQ(helped.block_count(), unaided.block_count()) << "a wall " << depth << " m off";
    }
    blocks_seen += helped.block_count();
  }
  EXPECT_GT(blocks_seen, 500u) << "the walls cross the band";
}

TEST(ExpectedSurface, NoNearPointsLeaveNoPixelAndNoBlock) {
  const std::vector<Vec3f> none;
  TsdfOptions o;
  o.voxel_m = kVoxel, o.near_points = &none, o.near_margin_m = 0.1;
  TsdfVolume volume(o);
  const PinholeCamera camera = PinholeCamera::FromFov(40, 30, 70);
  const Iso3 T_volume_camera = LookAt(Vec3(2, 0, 1), Vec3(0, 0, 0.4));
  const PixelMask mask = volume.NearPixels(camera, T_volume_camera);
  ASSERT_EQ(mask.size(), 40u * 30u);
  EXPECT_EQ(std::count(mask.begin(), mask.end(), 0), 40 * 30);
  auto caster = RayCaster::Create(Box(0.4f, 0.4f, 0.8f));
  ASSERT_TRUE(caster.ok());
  std::vector<float> incidence;
  const RangeImage range = caster->Render(camera, T_volume_camera, 8.0, &incidence);
  ASSERT_TRUE(volume.Integrate(camera, T_volume_camera, range, incidence).ok());
  EXPECT_EQ(volume.block_count(), 0u);
}

TEST(ExpectedSurface, MedianEdgeLengthIsTheGridStep) {
  TriangleMesh grid;  // 10 x 10 squares of 1 cm, two triangles each
  for (int y = 0; y <= 10; ++y)
    for (int x = 0; x <= 10; ++x) grid.vertices.push_back({0.01f * x, 0.01f * y, 0});
  for (std::uint32_t y = 0; y < 10; ++y)
    for (std::uint32_t x = 0; x < 10; ++x) {
      const std::uint32_t v = y * 11 + x;
      grid.triangles.push_back({v, v + 1, v + 12});
      grid.triangles.push_back({v, v + 12, v + 11});
    }
  EXPECT_NEAR(MedianEdgeLength(grid), 0.01, 1e-6);
  EXPECT_EQ(MedianEdgeLength(TriangleMesh{}), 0.0);
}

TEST(RobotSide, ExpectedSurfacesAreCachedPerVoxelAndWalk) {
  auto robot = RobotModel::Load(testing::BuiltinRobotUrdf());
  ASSERT_TRUE(robot.ok()) << robot.status().ToString();
  auto side = RobotSide::Create(*robot, {}, 3000, 1);
  ASSERT_TRUE(side.ok()) << side.status().ToString();
  EXPECT_EQ((*side)->samples().size(), 3000u);
  auto a = (*side)->Expected(kVoxel);
  auto b = (*side)->Expected(kVoxel + 0.0002);  // the same millimetre: the same surface
  auto walk = (*side)->Expected(kVoxel, 0);
  ASSERT_TRUE(a.ok() && b.ok() && walk.ok());
  EXPECT_EQ(a->get(), b->get());
  EXPECT_NE(a->get(), walk->get());
  EXPECT_EQ((*a)->size(), 3000u);
  auto bad = (*side)->Expected(kVoxel, RobotSide::kWalks);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().ToString().find("walk"), std::string::npos);
}

// A client sending meshes of ever new resolutions must not grow the cache without end: the
// least recently used voxel size goes, and what a request still holds stays valid.
TEST(RobotSide, KeepsOnlyTheMostRecentVoxelSizes) {
  ASSERT_OK_AND_ASSIGN(const RobotModel robot, RobotModel::Load(testing::BuiltinRobotUrdf()));
  ASSERT_OK_AND_ASSIGN(const auto side, RobotSide::Create(robot, {}, 2000, 1));
  ASSERT_OK_AND_ASSIGN(const auto first, side->Expected(0.06));
  const std::size_t first_points = first->size();
  for (std::size_t i = 1; i <= RobotSide::kVoxelSizesKept; ++i) {
    ASSERT_TRUE(side->Expected(0.06 + 0.01 * static_cast<double>(i)).ok());
    EXPECT_EQ(side->voxel_sizes_kept(), std::min(i + 1, RobotSide::kVoxelSizesKept));
  }
  EXPECT_EQ(first->size(), first_points);  // dropped from the cache, still held here
  ASSERT_OK_AND_ASSIGN(const auto again, side->Expected(0.06));  // made anew
  EXPECT_NE(again.get(), first.get());
  ASSERT_OK_AND_ASSIGN(const auto recent, side->Expected(0.06 + 0.01 * RobotSide::kVoxelSizesKept));
  ASSERT_OK_AND_ASSIGN(const auto recent_again, side->Expected(0.06 + 0.01 * RobotSide::kVoxelSizesKept));
  EXPECT_EQ(recent.get(), recent_again.get());  // the recent ones stay
  EXPECT_EQ(side->voxel_sizes_kept(), RobotSide::kVoxelSizesKept);
  // A cancelled build of a new size keeps nothing and pushes none of the kept sizes out.
  const std::array<double, 4> kept_voxels = {0.06, 0.08, 0.09, 0.10};
  std::vector<std::shared_ptr<const PointCloud>> kept;
  for (const double voxel : kept_voxels) {
    ASSERT_OK_AND_ASSIGN(auto surface, side->Expected(voxel));
    kept.push_back(surface);
  }
  CancelToken cancelled;
  cancelled.Cancel();
  EXPECT_EQ(side->Expected(0.2, -1, 0, &cancelled).status().code(), StatusCode::kCancelled);
  EXPECT_EQ(side->voxel_sizes_kept(), RobotSide::kVoxelSizesKept);
  for (std::size_t i = 0; i < kept.size(); ++i) {
    ASSERT_OK_AND_ASSIGN(const auto still, side->Expected(kept_voxels[i]));
    EXPECT_EQ(still.get(), kept[i].get()) << kept_voxels[i] << " m voxels' surface was made anew";
  }
}

}  // namespace
}  // namespace arref
