// Simulated rooms: the arms are where their ground truth says (the mapped mesh lies on them),
// the requested count of each, reproducible from the seed, and bad options are refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

#include "arref/robot/robot_model.h"
#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/sampling.h"
#include "arref/sim/room_simulator.h"
#include "builtin_robot.h"
#include "test_support.h"

namespace arref::sim {
namespace {

using testing::BuiltinRobot;

TriangleMesh Merged(const SimulatedRoom& room) {
  SpatialMesh map;
  for (const Surface& s : room.surfaces) EXPECT_TRUE(map.Upsert(s).ok());
  return *map.MergedWorld();
}

// Share of the arm's surface samples (posed at its ground truth) within `within_m` of the mapped mesh.
double ShareOnMesh(const RobotModel& robot, const RoomArm& arm, const PointIndex& mesh_points, double within_m) {
  auto posed = robot.PosedMesh(arm.joints);
  EXPECT_TRUE(posed.ok());
  PointCloud samples = SampleSurface(*posed, 2000, 3);
  samples.Transform(arm.T_world_base);
  std::size_t near = 0;
  for (const Vec3f& p : samples.points) near += mesh_points.AnyWithin(p, static_cast<float>(within_m * within_m));
  return static_cast<double>(near) / static_cast<double>(samples.size());
}

TEST(RoomSimulator, TwoArmsLieOnTheMappedMeshWhereTheTruthSays) {
  RoomOptions options;
  options.arms = 2;
  options.max_side_m = 7.0;
  ASSERT_OK_AND_ASSIGN(const SimulatedRoom room, SimulateRoom({&BuiltinRobot(), nullptr}, options, 5));
  ASSERT_EQ(room.arms.size(), 2u);
  const TriangleMesh mesh = Merged(room);
  EXPECT_GT(mesh.triangles.size(), 20000u);
  const PointIndex index(SampleSurface(mesh, 400000, 1).points);
  for (const RoomArm& arm : room.arms) {
    EXPECT_TRUE(arm.requested);
    EXPECT_TRUE(arm.placement == "wall" || arm.placement == "table" || arm.placement == "open") << arm.placement;
    // A walker maps about half of an arm (the rest faces away or down); a wrong truth puts none of it on the mesh.
    EXPECT_GT(ShareOnMesh(BuiltinRobot(), arm, index, 2.5 * room.voxel_m), 0.35);
    // The base stands on the floor or its pedestal: height above the floor as drawn.
    const double floor_z = room.T_world_room.translation().z();
    EXPECT_NEAR(arm.T_world_base.translation().z() - floor_z, arm.pedestal_m, 1e-9);
    // Where the walk's tracking errors (4 mm, 0.3 deg per view) put the arm in the map: measured,
    // millimetres off, and gravity aligned (a move and a turn about the vertical only).
    ASSERT_TRUE(arm.T_world_base_mesh.has_value());
    EXPECT_GT(arm.mesh_error_add_m, 0.0);
    EXPECT_LT(arm.mesh_error_add_m, 0.02);
    const Iso3 T_mesh_true = *arm.T_world_base_mesh * arm.T_world_base.inverse();
    EXPECT_LT(T_mesh_true.translation().norm(), 0.03);
    EXPECT_NEAR(T_mesh_true.linear()(2, 2), 1.0, 1e-9);
  }
  EXPECT_GT((room.arms[0].T_world_base.translation() - room.arms[1].T_world_base.translation()).norm(), 0.3);
}

TEST(RoomSimulator, WithoutHeadTrackingErrorTheMapPutsTheArmWhereItStands) {
  RoomOptions options;
  options.max_side_m = 6.0;
  ASSERT_OK_AND_ASSIGN(const SimulatedRoom with, SimulateRoom({&BuiltinRobot(), nullptr}, options, 11));
  options.without = {"view-jitter"};
  ASSERT_OK_AND_ASSIGN(const SimulatedRoom without, SimulateRoom({&BuiltinRobot(), nullptr}, options, 11));
  // The same room and arm; only the views' tracking error is gone, and with it the mesh error.
  ASSERT_EQ(without.arms.size(), 1u);
  EXPECT_TRUE(without.arms[0].T_world_base.isApprox(with.arms[0].T_world_base));
  EXPECT_GT(with.arms[0].mesh_error_add_m, 0.0005);
  EXPECT_GE(without.arms[0].mesh_error_add_m, 0.0);
  EXPECT_LT(without.arms[0].mesh_error_add_m, 1e-6);
}

TEST(RoomSimulator, SameSeedSameRoomAndNoArmWhenNoneIsAsked) {
  RoomOptions options;
  options.arms = 0;
  options.max_side_m = 5.0;
  ASSERT_OK_AND_ASSIGN(const SimulatedRoom a, SimulateRoom({&BuiltinRobot(), nullptr}, options, 9));
  ASSERT_OK_AND_ASSIGN(const SimulatedRoom b, SimulateRoom({&BuiltinRobot(), nullptr}, options, 9));
  EXPECT_TRUE(a.arms.empty());
  EXPECT_EQ(a.triangles, b.triangles);
  EXPECT_TRUE(a.T_world_room.isApprox(b.T_world_room));
  EXPECT_TRUE(std::none_of(a.props.begin(), a.props.end(), [](const Prop& p) { return p.kind == "robot"; }));
}

TEST(RoomSimulator, RefusesBadOptions) {
  RoomOptions options;
  options.arms = 3;
  EXPECT_EQ(SimulateRoom({&BuiltinRobot(), nullptr}, options, 1).status().code(), StatusCode::kInvalidArgument);
  options.arms = 1;
  options.other_arm = true;  // no other model given
  EXPECT_EQ(SimulateRoom({&BuiltinRobot(), nullptr}, options, 1).status().code(), StatusCode::kInvalidArgument);
  options.other_arm = false;
  options.max_side_m = 30;
  const auto st = SimulateRoom({&BuiltinRobot(), nullptr}, options, 1).status();
  EXPECT_NE(st.ToString().find("room sides"), std::string::npos) << st.ToString();
  options.max_side_m = 10;
  options.without = {"sunlight"};
  const auto unknown = SimulateRoom({&BuiltinRobot(), nullptr}, options, 1).status();
  EXPECT_EQ(unknown.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(unknown.ToString().find("sunlight"), std::string::npos) << unknown.ToString();
}

}  // namespace
}  // namespace arref::sim
