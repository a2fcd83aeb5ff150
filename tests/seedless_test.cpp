// Seedless referencing (arref-auto) on simulated rooms with ground truth: both arms of a two-arm
// room found and ranked, the hint picks the primary, a room without the robot is FAILED.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <limits>
#include <utility>
#include <vector>

#include "arref/fusion/robot_side.h"
#include "arref/pipeline/seedless.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/metrics.h"
#include "arref/sim/room_simulator.h"
#include "builtin_robot.h"
#include "test_support.h"

namespace arref {
namespace {

using testing::BuiltinRobot;

TriangleMesh Merged(const sim::SimulatedRoom& room) {
  SpatialMesh map;
  for (const Surface& s : room.surfaces) EXPECT_TRUE(map.Upsert(s).ok());
  return *map.MergedWorld();
}

struct Room {
  sim::SimulatedRoom sim;
  TriangleMesh map;
  std::shared_ptr<const RobotSide> side;
};

Room MakeRoom(int arms, std::uint64_t seed) {
  sim::RoomOptions options;
  options.arms = arms;
  options.max_side_m = 7.0;
  auto sim = sim::SimulateRoom({&BuiltinRobot(), nullptr}, options, seed);
  if (!sim.ok()) throw std::runtime_error(sim.status().ToString());
  Room room{std::move(*sim), {}, {}};
  room.map = Merged(room.sim);
  const JointValues joints = room.sim.arms.empty() ? JointValues{} : room.sim.arms.front().joints;
  auto side = RobotSide::Create(BuiltinRobot(), joints, 10000, 1);
  if (!side.ok()) throw std::runtime_error(side.status().ToString());
  room.side = *side;
  return room;
}

double Add(const Room& room, const Iso3& T, const sim::RoomArm& arm) {
  return ComparePoses(T, arm.T_world_base, room.side->samples().points).add_m;
}

// The instance nearest an arm (null when there is none) and its ADD.
std::pair<const FoundInstance*, double> Nearest(const Room& room, const WholeMapReport& report, const sim::RoomArm& arm) {
  std::pair<const FoundInstance*, double> nearest{nullptr, 1e9};
  for (const FoundInstance& f : report.instances)
    if (const double add = Add(room, f.report.T_world_base, arm); add < nearest.second) nearest = {&f, add};
  return nearest;
}

TEST(Seedless, FindsBothArmsOfATwoArmRoomAndTheHintPicksThePrimary) {
  const Room room = MakeRoom(2, 3);
  ASSERT_EQ(room.sim.arms.size(), 2u);
  RegistrationOptions options;
  options.method = Method::kArrefAuto;
  int progress_calls = 0;
  ASSERT_OK_AND_ASSIGN(const WholeMapReport report,
                       RegisterWholeMap(*room.side, room.map, options, {}, [&](std::string_view, double) { ++progress_calls; }));
  EXPECT_GT(progress_calls, 3);
  EXPECT_GE(report.candidates, 2);
  ASSERT_GE(report.instances.size(), 2u);
  for (const sim::RoomArm& arm : room.sim.arms)
    EXPECT_LT(Nearest(room, report, arm).second, 0.02)
        << "an arm at " << arm.T_world_base.translation().transpose() << " was not found";
  for (const FoundInstance& f : report.instances) {  // each instance says how much of its place it explains
    EXPECT_GT(f.explained, 0.0);
    EXPECT_LE(f.explained, 1.0);
    EXPECT_GT(f.explained_bar, 0.5);
    EXPECT_LT(f.explained_bar, 1.0);
  }
  // The hint: the wearer stands by the second arm.
  InstanceHint hint;
  hint.wearer_position_world = room.sim.arms[1].T_world_base.translation() + Vec3(0.5, 0, 1.0);
  ASSERT_OK_AND_ASSIGN(const WholeMapReport hinted, RegisterWholeMap(*room.side, room.map, options, hint));
  ASSERT_GE(hinted.primary, 0);
  const Iso3& primary = hinted.instances[static_cast<std::size_t>(hinted.primary)].report.T_world_base;
  EXPECT_LT(Add(room, primary, room.sim.arms[1]), 0.02);
}

// A real arm whose fit is only too imprecise for an OK (its expected error over the bar) is still
// an instance: the explanation and distinct-pose checks are for maybes on clutter, and a large
// arm's true fits explain less of the map round them than those checks ask (docs/seedless.md).
TEST(Seedless, AnArmFoundButImpreciseIsStillAnInstance) {
  const Room room = MakeRoom(2, 3);
  ASSERT_EQ(room.sim.arms.size(), 2u);
  RegistrationOptions options;
  options.method = Method::kArrefAuto;
  options.confidence.ok_max_expected_error_m = 0.001;  // every fit of this map is over it
  ASSERT_OK_AND_ASSIGN(const WholeMapReport report, RegisterWholeMap(*room.side, room.map, options));
  EXPECT_EQ(report.status, ResultStatus::kLowConfidence) << report.status_reason;
  for (const sim::RoomArm& arm : room.sim.arms) {
    const auto [nearest, add] = Nearest(room, report, arm);
    ASSERT_NE(nearest, nullptr);
    EXPECT_LT(add, 0.02) << "an arm at " << arm.T_world_base.translation().transpose() << " was dropped";
    EXPECT_TRUE(nearest->report.imprecise_only) << nearest->report.status_reason;
    EXPECT_NE(nearest->report.status_reason.find("expected error"), std::string::npos) << nearest->report.status_reason;
  }
}

// The instances' order: OK fits first by score; of two placed but imprecise fits, the smaller
// expected error first whatever their scores (a fit over the map's flat parts can hold more of the
// model, as the MH5's farther-off instance did in a dev room, docs/seedless.md); an unmeasured
// expected error last among them; LOW_CONFIDENCE fits that are not placed by score, after both.
TEST(Seedless, InstancesRankOkByScoreAndImpreciseFitsByExpectedError) {
  auto instance = [](ResultStatus status, bool imprecise_only, double score, double expected_m) {
    FoundInstance f;
    f.report.status = status;
    f.report.imprecise_only = imprecise_only;
    f.report.score = score;
    f.report.precision.expected_error_m = expected_m;
    return f;
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<FoundInstance> found = {
      instance(ResultStatus::kLowConfidence, false, 0.90, 0.005),  // 0: not placed
      instance(ResultStatus::kLowConfidence, true, 0.80, 0.016),   // 1: imprecise, better scored
      instance(ResultStatus::kLowConfidence, true, 0.60, 0.012),   // 2: imprecise, better placed
      instance(ResultStatus::kOk, false, 0.50, 0.009),             // 3
      instance(ResultStatus::kLowConfidence, true, 0.95, nan),     // 4: imprecise, unmeasured
      instance(ResultStatus::kOk, false, 0.70, 0.004),             // 5
      instance(ResultStatus::kLowConfidence, false, 0.40, 0.003),  // 6: not placed
  };
  for (std::size_t i = 0; i < found.size(); ++i) found[i].detection_score = static_cast<double>(i);
  std::stable_sort(found.begin(), found.end(), RanksBefore);
  std::vector<int> order;
  for (const auto& f : found) order.push_back(static_cast<int>(f.detection_score));
  EXPECT_EQ(order, (std::vector<int>{5, 3, 2, 1, 4, 0, 6}));
  EXPECT_FALSE(RanksBefore(found[2], found[2])) << "irreflexive";
}

TEST(Seedless, ARoomWithoutTheRobotIsFailedWithNoInstanceOk) {
  const Room room = MakeRoom(0, 4);
  RegistrationOptions options;
  options.method = Method::kArrefAuto;
  ASSERT_OK_AND_ASSIGN(const WholeMapReport report, RegisterWholeMap(*room.side, room.map, options));
  EXPECT_GT(report.candidates, 0);
  EXPECT_NE(report.status, ResultStatus::kOk);
  EXPECT_TRUE(std::none_of(report.instances.begin(), report.instances.end(),
                           [](const FoundInstance& f) { return f.report.status == ResultStatus::kOk; }));
}

// A small arm (the Yaskawa MH5, under 1 m) fits clutter partly: a room without it must still be
// FAILED with no pose, not an instance on a box or a shelf. Room 2 of these once gave an OK on
// clutter (inliers 0.31, margin 0.29) that passed arref-icp's own checks; it scored only 0.05
// above the room's other clutter fits, which the room-wide margin now asks of an OK.
TEST(Seedless, ARoomWithoutASmallArmIsFailed) {
  const std::string urdf = testing::SharedDir() + "/robots/motoman_mh5_support/urdf/mh5.urdf";
  if (!std::filesystem::exists(urdf)) GTEST_SKIP() << urdf << " not found: the vendor MH5 package is only beside CI's and developers' clones";
  ASSERT_OK_AND_ASSIGN(const RobotModel mh5, RobotModel::Load(urdf, RobotLoadOptions{.package_path = {testing::SharedDir() + "/robots"}}));
  ASSERT_OK_AND_ASSIGN(const std::shared_ptr<const RobotSide> side, RobotSide::Create(mh5, JointValues{}, 10000, 1));
  RegistrationOptions options;
  options.method = Method::kArrefAuto;
  for (const std::uint64_t seed : {1u, 2u, 3u}) {
    sim::RoomOptions room_options;
    room_options.arms = 0;
    room_options.max_side_m = 7.0;
    ASSERT_OK_AND_ASSIGN(const sim::SimulatedRoom room, sim::SimulateRoom({&mh5, nullptr}, room_options, seed));
    ASSERT_OK_AND_ASSIGN(const WholeMapReport report, RegisterWholeMap(*side, Merged(room), options));
    EXPECT_GT(report.candidates, 0) << "room " << seed;
    EXPECT_EQ(report.status, ResultStatus::kFailed) << "room " << seed << ": " << report.status_reason;
    for (const auto& instance : report.instances)
      ADD_FAILURE() << "room " << seed << ": an instance said " << ResultStatusName(instance.report.status) << ", inliers "
                    << instance.report.inlier_fraction << ", margin " << instance.report.margin;
    EXPECT_EQ(report.primary, -1) << "room " << seed;
  }
}

// A LOW_CONFIDENCE fit must be a distinct pose to be an instance: in this Open3D room, which holds
// no MH5 (only a built-in arm), the MH5 laid on boxes fitted several poses alike and explained its
// place; before the rule it was returned as a LOW_CONFIDENCE instance (dev draws 4-13 had five
// such in 160 empty rooms, all MH5 on Open3D meshes, leading by 0.005-0.046). The result names
// the margin.
TEST(Seedless, ASmallArmsAmbiguousFitOnClutterIsNoInstance) {
  const std::string urdf = testing::SharedDir() + "/robots/motoman_mh5_support/urdf/mh5.urdf";
  if (!std::filesystem::exists(urdf)) GTEST_SKIP() << urdf << " not found: the vendor MH5 package is only beside CI's and developers' clones";
  if (!sim::MesherAvailable(sim::Mesher::kOpen3d)) GTEST_SKIP() << "Open3D's mesher is not built in";
  ASSERT_OK_AND_ASSIGN(const RobotModel mh5, RobotModel::Load(urdf, RobotLoadOptions{.package_path = {testing::SharedDir() + "/robots"}}));
  ASSERT_OK_AND_ASSIGN(const std::shared_ptr<const RobotSide> side, RobotSide::Create(mh5, JointValues{}, 10000, 1));
  sim::RoomOptions room_options;
  room_options.arms = 0;
  room_options.other_arm = true;
  room_options.mesher = sim::Mesher::kOpen3d;
  ASSERT_OK_AND_ASSIGN(const sim::SimulatedRoom room, sim::SimulateRoom({&mh5, &BuiltinRobot()}, room_options, 9));
  RegistrationOptions options;
  options.method = Method::kArrefAuto;
  ASSERT_OK_AND_ASSIGN(const WholeMapReport report, RegisterWholeMap(*side, Merged(room), options));
  EXPECT_EQ(report.status, ResultStatus::kFailed) << report.status_reason;
  for (const auto& instance : report.instances)
    ADD_FAILURE() << "an instance said " << ResultStatusName(instance.report.status) << ", margin " << instance.report.margin;
  EXPECT_NE(report.status_reason.find("distinct pose"), std::string::npos) << report.status_reason;
}

TEST(Seedless, ArrefAutoRefusesASeededRequestAndAnEmptyMap) {
  const Room room = MakeRoom(1, 6);
  RegistrationOptions options;
  options.method = Method::kArrefAuto;
  const auto seeded = RegisterScene(*room.side, room.map, room.sim.arms[0].T_world_base, options);
  EXPECT_EQ(seeded.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(seeded.status().ToString().find("no seed"), std::string::npos) << seeded.status().ToString();
  EXPECT_EQ(RegisterWholeMap(*room.side, TriangleMesh{}, options).status().code(), StatusCode::kFailedPrecondition);
}

#ifdef ARREF_WITH_PCL
// The paper's proposal as a baseline: one candidate at most, and never OK (it compares no
// alternative poses, so a nearby wrong fit cannot be ruled out).
TEST(Seedless, SlidingBoxBaselineGivesAtMostOneCandidateNeverOk) {
  const Room room = MakeRoom(1, 6);
  RegistrationOptions options;
  options.method = Method::kSlidingBoxShot;
  ASSERT_OK_AND_ASSIGN(const WholeMapReport report, RegisterWholeMap(*room.side, room.map, options));
  EXPECT_EQ(report.method, "sliding-box-shot");
  EXPECT_LE(report.instances.size(), 1u);
  EXPECT_NE(report.status, ResultStatus::kOk);
  EXPECT_TRUE(std::any_of(report.stages_run.begin(), report.stages_run.end(),
                          [](const std::string& s) { return s.rfind("boxes-", 0) == 0; }));
}
#endif

}  // namespace
}  // namespace arref
