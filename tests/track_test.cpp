// Continuous referencing: joint history, clock offset, pose filter, the posed
// model's ray cast and the tracker on simulated streams with ground truth.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <numbers>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "arref/base/stats.h"
#include "arref/fusion/raycaster.h"
#include "arref/sim/track_simulator.h"
#include "arref/sim/track_stream.h"
#include "arref/track/camera_pose_history.h"
#include "arref/track/clock_sync.h"
#include "arref/track/depth_noise.h"
#include "arref/track/joint_history.h"
#include "arref/track/model_caster.h"
#include "arref/track/pose_filter.h"
#include "arref/track/tracker.h"
#include "test_support.h"

namespace arref {
namespace {


std::shared_ptr<const RobotModel> Builtin() {
  auto robot = RobotModel::Load(testing::BuiltinRobotUrdf());
  if (!robot.ok()) return nullptr;
  return std::make_shared<const RobotModel>(std::move(robot).value());
}

TEST(JointHistory, InterpolatesHoldsAndRejectsBadSamples) {
  JointHistory h({"a", "b"}, {.keep_s = 1.0, .max_samples = 100, .max_extrapolation_s = 0.05});
  EXPECT_FALSE(h.At(0.0).ok());
  ASSERT_TRUE(h.Add(1.0, std::vector<double>{0.0, 1.0}).ok());
  ASSERT_TRUE(h.Add(1.1, std::vector<double>{0.2, 1.0}).ok());
  ASSERT_OK_AND_ASSIGN(JointLookup mid, h.At(1.05));
  EXPECT_NEAR(mid.joints.at("a"), 0.1, 1e-12);
  EXPECT_EQ(mid.staleness_s, 0.0);
  // Past the newest sample: the last velocity (2 rad/s) for at most 50 ms, then held.
  ASSERT_OK_AND_ASSIGN(JointLookup late, h.At(1.3));
  EXPECT_TRUE(late.extrapolated);
  EXPECT_NEAR(late.staleness_s, 0.2, 1e-12);
  EXPECT_NEAR(late.joints.at("a"), 0.3, 1e-12);
  // Out of order, wrong size, non-finite: errors that leave the history as it was.
  const Status older = h.Add(1.05, std::vector<double>{0.0, 0.0});
  EXPECT_EQ(older.message(), "joint state at 1.05 s is not newer than the last one (1.1 s)");
  EXPECT_FALSE(h.Add(1.2, std::vector<double>{0.0}).ok());
  EXPECT_FALSE(h.Add(1.2, std::vector<double>{NAN, 0.0}).ok());
  EXPECT_FALSE(h.Add(1.2, JointValues{{"a", 0.0}}).ok());
  EXPECT_EQ(h.size(), 2u);
  // Older than keep_s behind the newest: dropped.
  for (int i = 1; i <= 30; ++i) ASSERT_TRUE(h.Add(1.1 + 0.1 * i, std::vector<double>{0.0, 0.0}).ok());
  EXPECT_LE(h.size(), 11u);
  EXPECT_GE(h.size(), 10u);
}

TEST(ClockOffset, ShortestRoundTripGivesTheOffset) {
  ClockOffsetEstimator est(16);
  EXPECT_FALSE(est.Add({1.0, 2.0, 1.9, 1.2}).ok());  // reply sent before the request came
  const double offset = 0.731;  // ours minus the peer's
  const double delays[][2] = {{0.030, 0.002}, {0.004, 0.005}, {0.001, 0.0012}, {0.020, 0.001}};
  double t = 10.0;
  for (const auto& d : delays) {
    ClockExchange e{t - offset, t + d[0], t + d[0] + 0.0001, t + d[0] + 0.0001 + d[1] - offset};
    ASSERT_TRUE(est.Add(e).ok());
    t += 1.0;
  }
  EXPECT_NEAR(est.offset_s(), offset, est.uncertainty_s() + 1e-9);
  EXPECT_NEAR(est.uncertainty_s(), 0.5 * (0.001 + 0.0012), 1e-9);
}

TEST(PoseFilter, AveragesGatesAndFollowsAJump) {
  PoseFilter f({.drift_m_per_sqrt_s = 0.001, .drift_rad_per_sqrt_s = 0.0005, .gate_chi2 = 18.5, .jump_after = 3,
                .min_sigma_m = 0.0, .min_sigma_rad = 0.0});
  std::mt19937_64 rng(3);
  std::normal_distribution<double> n(0.0, 0.005);
  const Vec4 truth(1.0, -2.0, 0.5, 3.1);  // near pi: the yaw's wrap is part of the test
  const Mat4 R = Vec4(2.5e-5, 2.5e-5, 2.5e-5, 2.5e-5).asDiagonal();
  double t = 0;
  EXPECT_EQ(f.Update(truth + Vec4(n(rng), n(rng), n(rng), n(rng)), R, t), FilterVerdict::kInitialised);
  for (int i = 0; i < 100; ++i) {
    Vec4 z = truth + Vec4(n(rng), n(rng), n(rng), n(rng));
    z(3) = WrapAngle(z(3));
    EXPECT_EQ(f.Update(z, R, t += 0.033), FilterVerdict::kAccepted);
  }
  EXPECT_LT((f.state().head<3>() - truth.head<3>()).norm(), 0.003);  // better than one measurement's 8.7 mm
  EXPECT_LT(std::abs(WrapAngle(f.state()(3) - truth(3))), 0.003);
  EXPECT_LT(f.covariance()(0, 0), 2.5e-5);
  // One wild measurement is rejected and changes nothing.
  const Vec4 before = f.state();
  EXPECT_EQ(f.Update(truth + Vec4(0.3, 0, 0, 0), R, t += 0.033), FilterVerdict::kRejected);
  EXPECT_EQ(f.state(), before);
  EXPECT_EQ(f.Update(truth, R, t += 0.033), FilterVerdict::kAccepted);
  // A world jump: measurements agreeing with each other, far from the state.
  const Vec4 jumped = truth + Vec4(0.4, 0.2, 0.0, 0.3);
  EXPECT_EQ(f.Update(jumped, R, t += 0.033), FilterVerdict::kRejected);
  EXPECT_EQ(f.Update(jumped, R, t += 0.033), FilterVerdict::kRejected);
  EXPECT_EQ(f.Update(jumped, R, t += 0.033), FilterVerdict::kJump);
  EXPECT_LT((f.state().head<3>() - jumped.head<3>()).norm(), 1e-9);
  EXPECT_LT(std::abs(WrapAngle(f.state()(3) - jumped(3))), 1e-9);
}

TEST(ModelCaster, MatchesTheRayCastOfThePosedMesh) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  ASSERT_OK_AND_ASSIGN(ModelCaster caster, ModelCaster::Create(*robot));
  JointValues joints;
  for (const JointInfo& j : robot->ActuatedJoints()) joints[j.name] = 0.4;
  ASSERT_TRUE(caster.Pose(*robot, joints).ok());
  ASSERT_OK_AND_ASSIGN(TriangleMesh posed, robot->PosedMesh(joints));
  ASSERT_OK_AND_ASSIGN(RayCaster reference, RayCaster::Create(posed));
  const DepthIntrinsics c = DepthIntrinsics::FromFov(160, 144, 75.0);
  PinholeCamera pinhole;
  pinhole.width = c.width, pinhole.height = c.height, pinhole.focal_px = c.fx;
  const Iso3 T_base_camera = LookAt(Vec3(1.8, 0.6, 1.4), Vec3(0, 0, 0.6));
  const ModelView view = caster.Render(c, T_base_camera, 5.0, 1);
  const RangeImage range = reference.Render(pinhole, T_base_camera, 5.0);
  int hits = 0, same = 0;
  for (int v = 0; v < c.height; ++v)
    for (int u = 0; u < c.width; ++u) {
      const std::size_t p = static_cast<std::size_t>(v) * c.width + u;
      const double z_ref = range[p] > 0 ? range[p] / c.Ray(u, v).norm() : 0.0;
      if (z_ref > 0) ++hits;
      if ((z_ref > 0) == (view.z_depth[p] > 0) && std::abs(z_ref - view.z_depth[p]) < 1e-4) ++same;
    }
  EXPECT_GT(hits, 1000);
  EXPECT_GE(same, c.width * c.height - 5);  // edge pixels may round either way
  ASSERT_EQ(view.points_base.size(), static_cast<std::size_t>(hits) + (view.points_base.size() - hits));
  // Normals face the camera and lie on the surface the ray hit.
  for (std::size_t i = 0; i < view.points_base.size(); i += 50) {
    const Vec3 p = view.points_base.points[i].cast<double>(), n = view.points_base.normals[i].cast<double>();
    EXPECT_LT(n.dot(p - T_base_camera.translation()), 0.0);
    EXPECT_NEAR(n.norm(), 1.0, 1e-4);
  }
  EXPECT_TRUE(posed.vertices.size() > 0);
  EXPECT_TRUE(caster.bounds_base().Contains(BoundsOf(posed.vertices).min + Vec3f::Constant(1e-4f)));
}

TEST(PoseFilter, ConsistentButUnsupportedMeasurementsMakeNoJump) {
  PoseFilter f({.drift_m_per_sqrt_s = 0.001, .drift_rad_per_sqrt_s = 0.0005, .gate_chi2 = 18.5, .jump_after = 3,
                .min_sigma_m = 0.0, .min_sigma_rad = 0.0});
  const Vec4 truth(0.5, 0.2, 0.1, 0.3);
  const Mat4 R = Vec4(2.5e-5, 2.5e-5, 2.5e-5, 2.5e-5).asDiagonal();
  double t = 0;
  f.Update(truth, R, t);
  for (int i = 0; i < 20; ++i) EXPECT_EQ(f.Update(truth, R, t += 0.2), FilterVerdict::kAccepted);
  // A wrong basin 0.2 m off, the same on every frame, that explains the frames no better.
  const Vec4 basin = truth + Vec4(0.2, 0.0, 0.0, 0.05);
  for (int i = 0; i < 10; ++i) EXPECT_EQ(f.Update(basin, R, t += 0.2, false), FilterVerdict::kRejected);
  EXPECT_EQ(f.rejected_in_a_row(), 0);
  EXPECT_LT((f.state() - truth).norm(), 1e-9);
  // An unsupported one breaks a supported run; three supported ones in a row are a jump.
  EXPECT_EQ(f.Update(basin, R, t += 0.2, true), FilterVerdict::kRejected);
  EXPECT_EQ(f.Update(basin, R, t += 0.2, false), FilterVerdict::kRejected);
  EXPECT_EQ(f.Update(basin, R, t += 0.2, true), FilterVerdict::kRejected);
  EXPECT_EQ(f.Update(basin, R, t += 0.2, true), FilterVerdict::kRejected);
  EXPECT_EQ(f.Update(basin, R, t += 0.2, true), FilterVerdict::kJump);
  EXPECT_LT((f.state() - basin).norm(), 1e-9);
}

struct StreamOutcome {
  int scored = 0, within_10mm = 0, frames = 0;
  int rereferences_before_jump = 0;  // jumps and re-acquisitions after the first frame while the world had not moved
  double recovery_s = -1;            // as the bench counts it (sim::JumpRecovery)
  std::vector<double> add_m;         // ADD of every scored frame
  double depth_noise = 0;            // the tracker's measure of the depth's noise at the last frame
  double MedianAddM() const {
    std::vector<double> a = add_m;
    if (a.empty()) return std::nan("");
    std::nth_element(a.begin(), a.begin() + static_cast<std::ptrdiff_t>(a.size() / 2), a.end());
    return a[a.size() / 2];
  }
};

// Runs the tracker over a simulated stream as the server does: joint states through the
// history on the estimated clock offset, the tracker seeded off the truth.
// as_bench: the stream as `arref bench` runs it (its first guess for this seed, a round trip
// every tenth frame), so that a bench stream's failure reproduces here; otherwise a round trip
// every frame and a fixed first guess 6.4 cm across, 2 cm in height and 4 deg off.
StreamOutcome RunStream(std::shared_ptr<const RobotModel> robot, sim::TrackSimOptions options, std::uint64_t seed,
                        bool as_bench = false, double declared_pose_latency_s = 0.0,
                        const TrackerSettings& tracker = {}) {
  StreamOutcome out;
  auto simulator = sim::TrackSimulator::Create(robot, options, seed);
  EXPECT_TRUE(simulator.ok()) << simulator.status().ToString();
  if (!simulator.ok()) return out;
  sim::TrackStreamOptions stream;
  stream.declared_pose_latency_s = declared_pose_latency_s;
  stream.tracker = tracker;
  if (!as_bench) {
    stream.round_trip_every = 1;
    stream.first_guess = simulator->T_world_base_initial() * MakeYawPose(0.05, -0.04, 0.02, 4 * kDegree);
  }
  const double jump_time = simulator->jump_time_s();
  sim::JumpRecovery recovery(jump_time);
  const Status ran = sim::RunTrackStream(robot, *simulator, stream, [&](const sim::TrackStreamStep& step) {
    const sim::SimFrame& f = step.frame;
    ++out.frames;
    out.depth_noise = step.result.depth_noise_fraction;
    const TrackState state = step.result.state;
    if (step.index > 0 && !f.after_jump && (state == TrackState::kJump || state == TrackState::kReacquired))
      ++out.rereferences_before_jump;
    recovery.Add(step);
    if (sim::SettlingFrame(f, jump_time)) return Status::Ok();
    ++out.scored;
    out.add_m.push_back(step.add_m);
    if (step.add_m < 0.010) ++out.within_10mm;
    return Status::Ok();
  });
  EXPECT_TRUE(ran.ok()) << ran.ToString();
  out.recovery_s = recovery.recovery_s();
  return out;
}

// A stream that scored more than min_scored frames, made no re-reference before the jump,
// recovered from it (within max_recovery_s when given) and kept `share` of its frames within 10 mm.
void ExpectTracked(const StreamOutcome& o, int min_scored, double share,
                   std::optional<double> max_recovery_s = std::nullopt) {
  ASSERT_GT(o.scored, min_scored);
  EXPECT_EQ(o.rereferences_before_jump, 0);
  EXPECT_GE(o.recovery_s, 0.0) << "never recovered from the jump";
  if (max_recovery_s) {
    EXPECT_LE(o.recovery_s, *max_recovery_s);
  }
  EXPECT_GE(o.within_10mm, share * o.scored) << o.within_10mm << " of " << o.scored;
}

TEST(Tracker, FollowsAMovingRobotThroughAWorldJumpLongThrow) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  sim::TrackSimOptions options;
  options.duration_s = 5.0;
  options.jump_at_s = 2.5;
  const StreamOutcome o = RunStream(robot, options, 11);
  EXPECT_EQ(o.frames, 150);
  ASSERT_GT(o.scored, 60);
  EXPECT_GE(o.within_10mm, 0.9 * o.scored) << o.within_10mm << " of " << o.scored;
  EXPECT_GE(o.recovery_s, 0.0);
  EXPECT_LE(o.recovery_s, 1.0);
}

// A thin 7-axis arm half hidden behind a prop when the world jumps 0.5 m (the bench's dev
// stream 4 of the SIA10D in long-throw frames, by its simulator seed): the camera's view of the
// jump is right, and taken although it covers under half of the visible model.
TEST(Tracker, RecoversAHalfHiddenThinArmAfterAJump) {
  ARREF_REQUIRE_SHARED();
  auto loaded = RobotModel::Load(testing::SharedDir() + "/robots/motoman_sia10d_support/urdf/sia10d.urdf",
                                 RobotLoadOptions{.package_path = {testing::SharedDir() + "/robots"}});
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  auto robot = std::make_shared<const RobotModel>(std::move(*loaded));
  sim::TrackSimOptions options;
  options.duration_s = 12.0;  // the jump half way, as the bench's streams
  const StreamOutcome o = RunStream(robot, options, 11433870624494111265ull);
  ASSERT_GT(o.scored, 250);
  EXPECT_GE(o.recovery_s, 0.0) << "never recovered from the jump";
  EXPECT_LE(o.recovery_s, 1.0);
  EXPECT_GE(o.within_10mm, 0.9 * o.scored) << o.within_10mm << " of " << o.scored;
}

// The built-in robot's dev stream 2 in long-throw frames (the bench's simulator seed), without
// its jump: at the far end of the wearer's walk (8-11.5 s) the depth lies in front of 85-95 % of
// the robot's visible pixels, and ICP from the filter's pose (a few mm off) is pulled 4-22 cm
// away by that occluder in the crop, agreeing worse with the frame than its start did. Fused,
// such fits walked the filter 1-3 cm off: 222 of 330 frames within 10 mm. Now the occluder's
// depth is left out of the fit, a fit's covariance grows as the robot's agreeing share shrinks,
// and a fit agreeing clearly worse than its start is not fused: 284 (each of the three alone:
// 233-237, without the occluder's removal 267).
TEST(Tracker, HoldsThePoseWhileClutterPullsTheFits) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  sim::TrackSimOptions options;
  options.duration_s = 12.0;
  options.jump_at_s = 100.0;  // none: the drift is not the jump's
  const StreamOutcome o = RunStream(robot, options, 11387873304532188844ull);
  ASSERT_GT(o.scored, 300);
  EXPECT_EQ(o.rereferences_before_jump, 0);
  EXPECT_GE(o.within_10mm, 0.83 * o.scored) << o.within_10mm << " of " << o.scored;
}

// The built-in robot's stream 0 in long-throw frames of the held-back draw --rng-seed 18 (the
// bench's simulator seed; a development stream since that draw was looked at). After its 0.68 m
// jump the re-referenced filter started 9 mm and 0.7 deg off, and each fit from it stopped a step
// or two later on ICP's flat-cost test, so the filter took its own error back as a measurement
// and sat 12-17 mm off for 1.1 s with the arm in view: 281 of 330 frames within 10 mm, recovered
// in 1.10 s. The tracker's fits now run until their step is tiny: 312, recovered in 0.73 s.
// Since fits weigh with the cube of their coverage (FitsOnAPartlyHiddenArmWeighLess), the
// restarted pose holds a little longer against fits covering 85-95 % of the arm: 298, 1.00 s.
TEST(Tracker, FitsFromARestartedFilterDoNotEchoIt) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  sim::TrackSimOptions options;
  options.duration_s = 12.0;
  const StreamOutcome o = RunStream(robot, options, 11195231765048928583ull, true);
  ExpectTracked(o, 250, 0.92, 1.05);
}

std::shared_ptr<const RobotModel> SharedRobot(const std::string& urdf) {
  auto loaded = RobotModel::Load(testing::SharedDir() + "/robots/" + urdf,
                                 RobotLoadOptions{.package_path = {testing::SharedDir() + "/robots"}});
  if (!loaded.ok()) return nullptr;
  return std::make_shared<const RobotModel>(std::move(*loaded));
}

// A simulated stream of `kind` frames by its simulator seed; the world jumps at the simulator's
// default time (half way) unless jump_at_s is given. No frames scored when the robot does not load.
StreamOutcome StreamOf(std::shared_ptr<const RobotModel> robot, sim::FrameKind kind, double duration_s,
                       std::uint64_t seed, std::optional<double> jump_at_s = std::nullopt, bool as_bench = false) {
  if (!robot) {
    ADD_FAILURE() << "the robot does not load";
    return {};
  }
  sim::TrackSimOptions options;
  options.kind = kind;
  options.duration_s = duration_s;
  if (jump_at_s) options.jump_at_s = *jump_at_s;
  return RunStream(robot, options, seed, as_bench);
}

// A stream as the bench draws it (12 s, its first guess), by the bench's simulator seed.
StreamOutcome BenchStream(const std::string& urdf, std::uint64_t seed, sim::FrameKind kind) {
  return StreamOf(SharedRobot(urdf), kind, 12.0, seed, std::nullopt, true);
}

StreamOutcome AhatDevStream(const std::string& urdf, std::uint64_t seed) {
  return BenchStream(urdf, seed, sim::FrameKind::kAhat);
}

StreamOutcome LongThrowDevStream(const std::string& urdf, std::uint64_t seed) {
  return BenchStream(urdf, seed, sim::FrameKind::kLongThrow);
}

// The MH5's dev stream 3 in AHAT frames (the bench's simulator seed): from 3.8 s the arm is half
// to wholly hidden behind a prop, its true pose agreeing with every pixel it shows but covering
// 0.02-0.47 of its visible model. Poses 0.2-0.3 m off laid on the prop covered 0.6-0.8 and
// replaced the filter at 4.1 s: the stream never came back (139 of 495 frames within 10 mm).
// Now a pose found by search must be seen through less than the filter's (which nothing sees
// through), and a wholly hidden filter pose holds.
TEST(Tracker, HoldsAnArmHiddenBehindAPropInWrappedDepth) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = AhatDevStream("motoman_mh5_support/urdf/mh5.urdf", 3349603588497037793ull);
  ExpectTracked(o, 400, 0.7);
}

// The KR5 arc's dev stream 5 in AHAT frames: at the jump (6 s) the arm is 85 % hidden, most of it
// behind an occluder near the camera that reads, aliased by the 1 m wrap, as depth behind it.
// The camera's view of the jump was right but covered 0.14-0.19 of its visible model (under the
// 0.25 bar), and a search pose 0.6 m off was taken instead (225 of 495 frames within 10 mm). Its
// readable coverage (ambiguous pixels left out) is 0.44-0.53.
TEST(Tracker, TakesTheCameraViewOfAnArmHiddenByANearOccluder) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = AhatDevStream("kuka_kr5_support/urdf/kr5_arc.urdf", 2894739381230229186ull);
  ExpectTracked(o, 400, 0.9, 1.0);
}

// The SIA10D's stream 0 of the held-out split in long-throw frames (made a development stream
// on 2026-12-03 to find the split's one catastrophic row). At 8.4-8.8 s the arm is wholly behind
// a prop: every visible model pixel has depth in front of it, nothing agrees and nothing is seen
// through. The filter's pose read as explaining nothing (support 0), a search found a pose
// 1.14 m off laid on the prop, and it was never left (231 of 330 frames within 10 mm). A hidden
// filter pose now holds in long-throw frames as in AHAT ones.
TEST(Tracker, HoldsAnArmWhollyHiddenInLongThrowDepth) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = LongThrowDevStream("motoman_sia10d_support/urdf/sia10d.urdf", 13399427928172894881ull);
  ExpectTracked(o, 250, 0.9);
}

// The MH5's stream 0 of the held-out split at --rng-seed 5 in long-throw frames (a development
// stream since that look): the world jumps 1.04 m at 6 s, and the filter's stale pose, laid where
// the new view shows depth about as far as the arm's, went on agreeing 0.78-1.00 with a third of
// its pixels for 2.2 s, so its fits held it (264 of 330 frames within 10 mm). While a jump is
// pending the camera's view now challenges the filter on every frame and wins ties.
TEST(Tracker, LeavesAStalePoseThatStillAgreesAfterAJump) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = LongThrowDevStream("motoman_mh5_support/urdf/mh5.urdf", 14529820317515863789ull);
  ExpectTracked(o, 250, 0.95, 1.0);
}

// The SIA10D's dev stream 5 in AHAT frames: the world jumps 0.31 m at 6 s with 6-16 % of the arm
// readable. ICP from the camera's view slid along the props without fitting, and when a tie with
// the filter's (hidden, agreeing 0.00) was enough for the view of a pending jump, a slid pose
// 0.4 m off was taken and never left (225 of 495 frames within 10 mm); the view must fit.
TEST(Tracker, TakesNoUnfittedViewOfAPendingJump) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = AhatDevStream("motoman_sia10d_support/urdf/sia10d.urdf", 5347685757459918866ull);
  ExpectTracked(o, 400, 0.9);
}

// The SIA10D's held-back AHAT stream 1 of --rng-seed 12 (the bench's simulator seed; its look is
// spent, so it is a development stream now): after a 0.55 m jump the camera's view agreed on
// 3,036 pixels but lost on the readable share to the stale pose's few readable ones, and the stale
// pose's fits slid 0.69 m onto a pose with most of the arm out of view, where the filter jumped and
// stayed (225 of 495 frames within 10 mm, never recovered). A view agreeing on at least as many
// pixels as the filter's explanation is as good.
TEST(Tracker, TakesTheCameraViewThatAgreesOnMorePixelsAfterAJump) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = AhatDevStream("motoman_sia10d_support/urdf/sia10d.urdf", 11240021024155796197ull);
  ExpectTracked(o, 400, 0.95, 1.0);
}

// The MH5's held-back AHAT stream 0 of --rng-seed 21 (the bench's simulator seed; a development
// stream since that look): the world jumps 0.61 m and 11 deg at 6 s with the arm 90-97 % hidden
// or ambiguous. ICP from the camera's view slid 146 mm and 42 deg onto the props, and that fit,
// agreeing on a third of its readable pixels against a stale pose that explained nothing, was
// confirmed as the jump's pose and held for 2 s (379 of 495 frames within 10 mm, recovered in
// 2.58 s). A fit from the camera's view that ends beyond ICP's reach from it, or turned more than
// a search step, slid, and re-references nothing.
TEST(Tracker, TakesNoViewThatSlidOffHeadTrackingsGuess) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = AhatDevStream("motoman_mh5_support/urdf/mh5.urdf", 6149868820398740157ull);
  ExpectTracked(o, 400, 0.9, 2.0);
}

// The SIA10D's long-throw stream 1 of the held-back --rng-seed 19 (the bench's simulator seed; a
// development stream since that look). From 7 s props hide 50-80 % of the arm; the fits on its
// unhidden part sat 10-30 mm off towards the camera frame after frame, and those fused while a
// half to a third of it showed moved the filter 10 mm off, where it held: 277 of 330 frames
// within 10 mm. A fit now weighs with the cube of its coverage, not the coverage alone.
TEST(Tracker, FitsOnAPartlyHiddenArmWeighLess) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = LongThrowDevStream("motoman_sia10d_support/urdf/sia10d.urdf", 4053243156926358166ull);
  ExpectTracked(o, 250, 0.93, 1.0);
}

// The MH5's AHAT stream 0 of the held-back --rng-seed 25 (the bench's simulator seed; a
// development stream since that look), its first 3 s without the jump. From the bench's first
// guess, 4 deg off, the first fit turned 15.6 deg into a basin covering 0.70 of the arm's pixels
// (the right pose covers 0.95), and the filter held it 32 mm off for 6 s: 177 of 495 frames within
// 10 mm. The first frame now looks at the guess's heading turned by the search's yaw steps too.
TEST(Tracker, AcquiresTheBestHeadingRoundTheFirstGuess) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = StreamOf(SharedRobot("motoman_mh5_support/urdf/mh5.urdf"), sim::FrameKind::kAhat, 3.0,
                                   4755577473737113684ull, 100.0, true);
  ASSERT_GT(o.scored, 80);
  EXPECT_EQ(o.rereferences_before_jump, 0);
  EXPECT_GE(o.within_10mm, 0.95 * o.scored) << o.within_10mm << " of " << o.scored;
}

// The SIA10D's AHAT stream 1 of the held-back --rng-seed 25 (the bench's simulator seed; a
// development stream since that look). After its jump half the arm is behind props or in
// ambiguous wrapped depth for 5 s: the fits agreed with all of their readable pixels (74-80 % of
// them) but covered under 0.6 of the arm, so none was fused, and the held pose drifted with the
// wearer's world to 13 mm off (439 of 495 frames within 10 mm). Such fits are now fused, weighing
// with the cube of their coverage, while the tracker stays lost and searches on: 493. (The
// pose such fits must not confirm: ConfirmsNoPoseLaidOnHalfTheArmInWrappedDepth.)
TEST(Tracker, FusesFitsOnAHalfHiddenArmInWrappedDepth) {
  ARREF_REQUIRE_SHARED();
  const StreamOutcome o = AhatDevStream("motoman_sia10d_support/urdf/sia10d.urdf", 930861468559918041ull);
  ExpectTracked(o, 400, 0.97, 1.0);
}

// The built-in robot's dev stream 1 in AHAT frames (the bench's simulator seed): after its jump
// the camera's view re-referenced the filter 99 mm off, laid on half the arm (coverage 0.47,
// readable share 0.57-0.60). Had fits on a half-hidden arm confirmed a pose at that readable
// share, they would have held it there: 225 of 495 frames within 10 mm. They need 0.7.
TEST(Tracker, ConfirmsNoPoseLaidOnHalfTheArmInWrappedDepth) {
  const StreamOutcome o = StreamOf(Builtin(), sim::FrameKind::kAhat, 12.0, 11094629291557883836ull, std::nullopt, true);
  ExpectTracked(o, 400, 0.9, 1.0);
}

// The built-in robot's dev stream 0 of draw 3 in AHAT frames (the bench's simulator seed): after
// its jump, fits on the half-hidden thin arm covering 0.31-0.39 of its visible pixels came out
// 6-41 mm off, biased alike frame after frame, and walked the filter from 8 to 13 mm off in a
// second: 457 of 495 bench frames within 10 mm (426 of the 450 this test scores: it fails).
// Such fits need a coverage of 0.4 now: 493 of 495 bench frames.
TEST(Tracker, FusesNoFitOnUnderFourTenthsOfAnArmInWrappedDepth) {
  const StreamOutcome o = StreamOf(Builtin(), sim::FrameKind::kAhat, 12.0, 2662133633610956940ull, std::nullopt, true);
  ExpectTracked(o, 400, 0.97, 1.0);
}

// A depth sensor three times as noisy as the long-throw camera the tolerances were set for (3 %
// of range): the built-in robot's dev stream 1 as the bench runs it with --track-depth-noise
// 0.03. With the fixed tolerance most of the arm's pixels disagreed with any pose, no pose
// reached the re-acquisition bar after the jump, and the stream was lost for good (63 of 330
// frames within 10 mm); with the tolerance widened by the noise its frames measure, 326.
TEST(Tracker, WidensItsToleranceForANoisierSensor) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  sim::TrackSimOptions options;
  options.duration_s = 12.0;
  options.depth_noise_fraction = 0.03;
  constexpr std::uint64_t kSeed = 16615216445230627375ull;
  const StreamOutcome o = RunStream(robot, options, kSeed, true);
  ExpectTracked(o, 250, 0.95, 1.0);
  EXPECT_NEAR(o.depth_noise, 0.03, 0.003);
  TrackerSettings fixed;
  fixed.reference_depth_noise = 0.0;
  const StreamOutcome f = RunStream(robot, options, kSeed, true, 0.0, fixed);
  EXPECT_LT(f.within_10mm, 0.5 * f.scored) << "the fixed tolerance held this stream: the test no longer shows the change";
  EXPECT_EQ(f.depth_noise, 0.0);
}

// A wrapped (AHAT) stream's noise is measured where the filter's model says how far the readings
// are, and reported, but the tolerance stays as set: widened with it, the dev draw's AHAT streams
// at 2 % and 3 % of range lost frames within 10 mm (docs/tracking.md, "Wrapped depth's noise").
// At 2 % the stream reads within 15 % of what the simulator draws at arm's length (2 % + 2 mm at
// the walk's 1.2 m), and it is tracked pose for pose as with the measure switched off.
TEST(Tracker, ReportsAWrappedStreamsNoiseWithoutActingOnIt) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  sim::TrackSimOptions options;
  options.kind = sim::FrameKind::kAhat;
  options.duration_s = 4.0;
  options.depth_noise_fraction = 0.02;
  const StreamOutcome o = RunStream(robot, options, 11);
  ASSERT_GT(o.scored, 60);
  const double drawn = 0.02 + 0.002 / 1.2;
  EXPECT_NEAR(o.depth_noise, drawn, 0.15 * drawn);
  TrackerSettings off;
  off.reference_depth_noise = 0.0;
  const StreamOutcome f = RunStream(robot, options, 11, false, 0.0, off);
  EXPECT_EQ(f.depth_noise, 0.0);
  EXPECT_EQ(f.add_m, o.add_m) << "the measure changed the wrapped stream's poses";
}

// Long-throw fits on a mostly hidden arm: the built-in robot's dev stream 2 (bench seed). Fits
// that saw a few tenths of the visible model erred the same way frame after frame and walked the
// filter past 10 mm (251 of 300 scored frames within 10 mm here, then 285; the KR5 arc's dev stream 4
// failed alike). Such fits are no longer fused, and the fit leaves out depth in front of
// the model by more than the agreement's tolerance (it kept occluder depth up to 8 cm in front).
// Since fits weigh with the cube of their coverage (FitsOnAPartlyHiddenArmWeighLess): 277.
TEST(Tracker, HoldsThroughFitsOnAMostlyHiddenArm) {
  const StreamOutcome o = StreamOf(Builtin(), sim::FrameKind::kLongThrow, 12.0, 11387873304532188844ull);
  ExpectTracked(o, 250, 0.92);
}

// The simulator says how much of the arm in view props hide, so that the bench can tell a slow
// recovery from an arm nothing could see: in the built-in robot's dev stream 2 (above) props
// hide most of it for a while; in the same stream's cell without walls, table and boxes only the
// floor is left, and the median frame shows 91 % of the robot's pixels (the floor hides the rest:
// depth behind it, 5-15 cm, in the image's lowest rows).
// Recovery is counted from the jump to the first of ten frames in a row within 10 mm (a run
// broken by one frame over starts again), and from when the arm first shows to that run.
TEST(JumpRecovery, CountsTheFirstSettledRunAfterTheJump) {
  const JointLookup joints;
  const TrackResult result;
  const std::vector<Vec3f> points;
  sim::SimFrame f;
  sim::JumpRecovery recovery(1.0);
  auto add = [&](double t, double add_mm, double visible) {
    f.true_time_s = t, f.after_jump = t >= 1.0, f.robot_visible_fraction = visible;
    recovery.Add(sim::TrackStreamStep{0, f, joints, result, add_mm / 1000, points});
  };
  int k = 0;
  auto at = [&] { return 0.9 + 0.1 * k++; };  // 10 frames a second, from before the jump
  add(at(), 2.0, 1.0);                      // before the jump: not counted
  for (int i = 0; i < 3; ++i) add(at(), 500.0, 0.2);  // 1.0-1.2 s: off, the arm hidden
  add(at(), 500.0, 0.9);                    // 1.3 s: the arm shows
  for (int i = 0; i < 9; ++i) add(at(), 4.0, 0.9);    // 1.4-2.2 s: nine frames within
  add(at(), 12.0, 0.9);                     // 2.3 s: the run breaks
  EXPECT_FALSE(recovery.recovered());
  EXPECT_LT(recovery.recovery_s(), 0.0);
  for (int i = 0; i < 10; ++i) add(at(), 4.0, 0.9);   // 2.4-3.3 s: ten in a row
  ASSERT_TRUE(recovery.recovered());
  EXPECT_NEAR(recovery.recovery_s(), 1.4, 1e-9);
  EXPECT_NEAR(recovery.after_shown_s(), 1.1, 1e-9);
  add(at(), 500.0, 0.9);  // later frames change nothing
  EXPECT_NEAR(recovery.recovery_s(), 1.4, 1e-9);
}

TEST(TrackSimulator, SaysHowMuchOfTheArmPropsHide) {
  auto robot = Builtin();
  auto VisibleFractions = [&](const sim::TrackSimOptions& options) {
    auto simulator = sim::TrackSimulator::Create(robot, options, 11387873304532188844ull);
    EXPECT_TRUE(simulator.ok()) << simulator.status().ToString();
    std::vector<double> out;
    for (int i = 0; simulator.ok() && i < simulator->frame_count(); ++i) {
      auto f = simulator->Next();
      if (f.ok() && f->robot_visible_fraction > 0.0) out.push_back(f->robot_visible_fraction);  // 0: out of view
    }
    std::sort(out.begin(), out.end());
    return out;
  };
  sim::TrackSimOptions options;
  options.duration_s = 12.0;
  const std::vector<double> cell = VisibleFractions(options);
  options.cell.walls = options.cell.table = false;
  options.cell.clutter_boxes = 0;
  const std::vector<double> bare = VisibleFractions(options);
  ASSERT_GT(cell.size(), 300u);
  ASSERT_GT(bare.size(), 300u);
  EXPECT_LT(cell.front(), 0.5);
  EXPECT_EQ(cell.back(), 1.0);
  EXPECT_GT(bare.front(), cell.front());
  EXPECT_GE(bare[bare.size() / 2], 0.85) << "the median frame of a bare cell shows nearly all of the arm";
  EXPECT_LT(cell[cell.size() / 2], bare[bare.size() / 2]);
}

// Flying pixels change only pixels on the clean frame's depth edges, each to a depth between its
// own and a neighbour's; the rest of the frame (noise, dropouts) stays as it was. A pose latency
// moves the reported camera pose by the head's motion and leaves the depth alone.
TEST(TrackSimulator, DeviceEffectsFlyingPixelsOnEdgesAndALatePose) {
  auto robot = Builtin();
  auto FrameAt = [&](const sim::TrackSimOptions& options, int index) {
    auto simulator = sim::TrackSimulator::Create(robot, options, 7);
    EXPECT_TRUE(simulator.ok()) << simulator.status().ToString();
    Result<sim::SimFrame> f = Status::Internal("no frame");
    for (int i = 0; simulator.ok() && i <= index; ++i) f = simulator->Next();
    EXPECT_TRUE(f.ok()) << f.status().ToString();
    return f.ok() ? *f : sim::SimFrame{};
  };
  sim::TrackSimOptions options;
  options.duration_s = 2.0;
  const sim::SimFrame clean = FrameAt(options, 20);
  options.flying_pixel_rate = 1.0;
  const sim::SimFrame flying = FrameAt(options, 20);
  const DepthFrame& a = clean.frame;
  const DepthFrame& b = flying.frame;
  ASSERT_EQ(a.depth_mm.size(), b.depth_mm.size());
  ASSERT_GT(a.depth_mm.size(), 0u);
  EXPECT_TRUE(a.T_world_camera.isApprox(b.T_world_camera));
  const int w = a.intrinsics.width, h = a.intrinsics.height;
  int changed = 0, between = 0;
  for (int v = 1; v + 1 < h; ++v)
    for (int u = 1; u + 1 < w; ++u) {
      const float d0 = a.DepthAt(u, v), d1 = b.DepthAt(u, v);
      if (d0 == d1) continue;
      ++changed;
      ASSERT_GT(d0, 0.0f) << "a pixel without a return gained one at " << u << "," << v;
      // The noise is 1 % of the depth: a mixed depth lies between the two sides within a few of it.
      const float slack = 0.05f * std::max(d0, d1);
      bool ok = false;
      for (const auto& [du, dv] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
        const float dn = a.DepthAt(u + du, v + dv);
        if (dn > 0 && d1 >= std::min(d0, dn) - slack && d1 <= std::max(d0, dn) + slack && std::abs(dn - d0) > 0.03f) ok = true;
      }
      between += ok;
    }
  EXPECT_GT(changed, 100) << "every edge pixel flies at rate 1";
  EXPECT_LT(changed, w * h / 10) << "only edge pixels fly";
  EXPECT_GE(between, changed * 97 / 100) << between << " of " << changed << " changed pixels lie between an edge's sides";

  options.flying_pixel_rate = 0.0;
  options.pose_latency_s = 0.1;
  const sim::SimFrame late = FrameAt(options, 20);
  EXPECT_EQ(late.frame.depth_mm, a.depth_mm);
  const double moved = (late.frame.T_world_camera.translation() - a.T_world_camera.translation()).norm();
  EXPECT_GT(moved, 0.005) << "0.1 s of a walk at 0.5 m/s";
  EXPECT_LT(moved, 0.2);

  options.pose_latency_s = 2.0;
  EXPECT_FALSE(sim::TrackSimulator::Create(robot, options, 7).ok());
  options.pose_latency_s = 0.0;
  options.flying_pixel_rate = 1.5;
  const auto bad = sim::TrackSimulator::Create(robot, options, 7);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().ToString().find("flying pixel rate 1.5"), std::string::npos) << bad.status().ToString();
}

// The depth noise measured from the frames themselves, on the simulator's long-throw frames with
// flying pixels on every depth edge (outliers the measure must ignore): within 15 % of the sigma
// the simulator draws, at the sensor's own 1 % of range and at 2 % and 4 %; none for a wrapped
// (AHAT) frame, whose readings are not ranges, or a frame with too few returns.
TEST(DepthNoise, MeasuresTheSensorsNoiseFromItsFrames) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  for (const double fraction : {0.01, 0.02, 0.04}) {
    sim::TrackSimOptions options;
    options.duration_s = 1.0;
    options.depth_noise_fraction = fraction;
    options.flying_pixel_rate = 1.0;
    ASSERT_OK_AND_ASSIGN(sim::TrackSimulator simulator, sim::TrackSimulator::Create(robot, options, 5));
    DepthNoiseEstimate estimate(10);
    for (int i = 0; i < 10; ++i) {
      ASSERT_OK_AND_ASSIGN(const sim::SimFrame f, simulator.Next());
      const std::optional<double> one = FrameDepthNoise(f.frame);
      ASSERT_TRUE(one.has_value());
      EXPECT_NEAR(*one, fraction, 0.25 * fraction) << "one frame";
      estimate.Add(*one);
    }
    ASSERT_TRUE(estimate.fraction().has_value());
    EXPECT_NEAR(*estimate.fraction(), fraction, 0.15 * fraction);
  }
  sim::TrackSimOptions ahat;
  ahat.kind = sim::FrameKind::kAhat;
  ahat.duration_s = 1.0;
  ASSERT_OK_AND_ASSIGN(sim::TrackSimulator wrapped, sim::TrackSimulator::Create(robot, ahat, 5));
  ASSERT_OK_AND_ASSIGN(const sim::SimFrame w, wrapped.Next());
  EXPECT_FALSE(FrameDepthNoise(w.frame).has_value());
  DepthFrame empty = w.frame;
  empty.wrap_m = 0.0;
  std::fill(empty.depth_mm.begin(), empty.depth_mm.end(), 0);
  EXPECT_FALSE(FrameDepthNoise(empty).has_value());
  DepthNoiseEstimate none;
  EXPECT_FALSE(none.fraction().has_value());
  none.Add(std::nan(""));
  EXPECT_FALSE(none.fraction().has_value());
}

// The same in wrapped (AHAT) frames, where the readings are ranges modulo 1 m and the walk's
// 1.2 m puts the arm's readings an alias nearer: measured at the pixels where the robot's model
// (posed at the truth, as the tracker's filter places it) says how far they are, within 25 % per
// frame and 15 % over ten of what the simulator draws there (a fraction of range plus a 2 mm
// floor), at AHAT's own noise and at 1 % and 2 %. Divided by the reading instead of its range it
// would read several times that. Nothing without a model's depth, or for an unwrapped frame.
TEST(DepthNoise, MeasuresWrappedFramesWhereTheModelSaysHowFarTheyAre) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  ASSERT_OK_AND_ASSIGN(ModelCaster caster, ModelCaster::Create(*robot));
  for (const double fraction : {0.003, 0.01, 0.02}) {
    sim::TrackSimOptions options;
    options.kind = sim::FrameKind::kAhat;
    options.duration_s = 1.0;
    options.depth_noise_fraction = fraction;
    ASSERT_OK_AND_ASSIGN(sim::TrackSimulator simulator, sim::TrackSimulator::Create(robot, options, 5));
    DepthNoiseEstimate estimate(10);
    std::vector<double> drawn;
    for (int i = 0; i < 10; ++i) {
      ASSERT_OK_AND_ASSIGN(const sim::SimFrame f, simulator.Next());
      ASSERT_TRUE(caster.Pose(*robot, f.joints_true).ok());
      const Iso3 T_base_camera = f.T_world_base_true.inverse() * f.frame.T_world_camera;
      const ModelView view = caster.Render(f.frame.intrinsics, T_base_camera, 5.0, 4);
      std::vector<double> ranges;
      for (const float z : view.z_depth)
        if (z > 0) ranges.push_back(z);
      ASSERT_GT(ranges.size(), 200u);
      const double z = Quantile(ranges, 0.5);
      ASSERT_GT(z, f.frame.wrap_m) << "the arm stands beyond the wrap: its readings alias";
      drawn.push_back(fraction + 0.002 / z);
      const std::optional<double> one = WrappedFrameDepthNoise(f.frame, view);
      ASSERT_TRUE(one.has_value());
      EXPECT_NEAR(*one, drawn.back(), 0.25 * drawn.back()) << "one frame at " << fraction;
      estimate.Add(*one);
      EXPECT_FALSE(FrameDepthNoise(f.frame).has_value());
      EXPECT_FALSE(WrappedFrameDepthNoise(f.frame, ModelView{}).has_value());
      DepthFrame unwrapped = f.frame;
      unwrapped.wrap_m = 0.0;
      EXPECT_FALSE(WrappedFrameDepthNoise(unwrapped, view).has_value());
    }
    ASSERT_TRUE(estimate.fraction().has_value());
    const double expected = Quantile(drawn, 0.5);
    EXPECT_NEAR(*estimate.fraction(), expected, 0.15 * expected) << fraction;
  }
}

// A camera turning at a constant rate about one axis while moving at a constant velocity:
// between two reports, slerp and a linear blend give its pose exactly.
TEST(CameraPoseHistory, InterpolatesBetweenReportsAndNothingOutside) {
  auto pose_at = [](double t) {
    Iso3 T = Iso3::Identity();
    T.linear() = Eigen::AngleAxisd(0.8 * t, Vec3(0.3, -0.2, 0.93).normalized()).toRotationMatrix();
    T.translation() = Vec3(1.0, 2.0, 1.6) + t * Vec3(0.5, -0.3, 0.05);
    return T;
  };
  CameraPoseHistory history;  // keeps CameraPoseHistory::kKeepS = 1 s
  EXPECT_FALSE(history.At(0.0).has_value()) << "no reports";
  for (int i = 0; i <= 60; ++i) history.Add(i / 30.0, pose_at(i / 30.0));
  for (double t : {1.5, 1.51, 1.987, 2.0}) {
    const auto T = history.At(t);
    ASSERT_TRUE(T.has_value()) << t;
    EXPECT_LT((T->matrix() - pose_at(t).matrix()).cwiseAbs().maxCoeff(), 1e-9) << t;
  }
  EXPECT_FALSE(history.At(2.01).has_value()) << "after the newest report";
  EXPECT_FALSE(history.At(0.9).has_value()) << "reports over a second behind the newest are dropped";
  history.Add(1.0, pose_at(1.0));  // out of order: a new history
  EXPECT_FALSE(history.At(1.5).has_value());
  EXPECT_TRUE(history.At(1.0).has_value());
  history.Clear();
  EXPECT_EQ(history.newest(), nullptr);
}

// A device that stamps its camera pose 60 ms after the exposure, at 30 fps with the wearer
// walking: told the latency, the tracker takes each frame's camera back to its exposure, and
// the pose it tracks is nearer the truth than when it is not told. A latency it cannot take is
// refused, named.
TEST(Tracker, TakesALateCameraPoseBackToTheExposure) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  sim::TrackSimOptions options;
  options.duration_s = 4.0;
  options.jump_at_s = 1000.0;  // none
  options.pose_latency_s = 0.06;
  const StreamOutcome untold = RunStream(robot, options, 5);
  const StreamOutcome told = RunStream(robot, options, 5, false, 0.06);
  options.pose_latency_s = 0.0;
  const StreamOutcome on_time = RunStream(robot, options, 5);
  ASSERT_GT(told.scored, 60);
  ASSERT_EQ(told.scored, untold.scored);
  EXPECT_LT(told.MedianAddM(), 0.75 * untold.MedianAddM())
      << "told " << told.MedianAddM() << " m, not told " << untold.MedianAddM() << " m";
  EXPECT_LT(told.MedianAddM(), on_time.MedianAddM() + 0.001)
      << "told " << told.MedianAddM() << " m, a device on time " << on_time.MedianAddM() << " m";
  EXPECT_GE(told.within_10mm, untold.within_10mm);

  ASSERT_OK_AND_ASSIGN(Tracker tracker, Tracker::Create(robot));
  for (double bad : {-0.01, 1.5, std::nan("")}) {
    const Status st = tracker.SetCameraPoseLatency(bad);
    EXPECT_EQ(st.code(), StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(st.message().find("camera pose latency"), std::string::npos) << st.ToString();
  }
  EXPECT_TRUE(tracker.SetCameraPoseLatency(0.02).ok());
}

TEST(Tracker, UnwrapsAhatDepth) {
  const StreamOutcome o = StreamOf(Builtin(), sim::FrameKind::kAhat, 3.0, 12, 100.0);  // no jump
  ASSERT_GT(o.scored, 60);
  EXPECT_GE(o.within_10mm, 0.9 * o.scored) << o.within_10mm << " of " << o.scored;
  EXPECT_EQ(o.rereferences_before_jump, 0);
}

// The world never moves: every frame stays with the first acquisition, at the long-throw
// camera's own rate (5 fps) where a frame's camera moves most between frames.
TEST(Tracker, NeverReReferencesAStillWorld) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  sim::TrackSimOptions options;
  options.duration_s = 40.0;
  options.fps = 5.0;
  options.jump_at_s = 1000.0;  // none
  const StreamOutcome o = RunStream(robot, options, 21);
  EXPECT_EQ(o.frames, 200);
  ASSERT_GT(o.scored, 150);
  EXPECT_EQ(o.rereferences_before_jump, 0);
  EXPECT_GE(o.within_10mm, 0.9 * o.scored) << o.within_10mm << " of " << o.scored;
}

TEST(Tracker, RejectsBadFramesAndNeedsASeed) {
  auto robot = Builtin();
  ASSERT_TRUE(robot);
  ASSERT_OK_AND_ASSIGN(Tracker tracker, Tracker::Create(robot));
  DepthFrame f;
  f.intrinsics = DepthIntrinsics::FromFov(32, 24, 75.0);
  f.depth_mm.assign(32 * 24, 1000);
  EXPECT_EQ(tracker.Process(f, {}).status().code(), StatusCode::kFailedPrecondition);
  tracker.Seed(Iso3::Identity());
  f.depth_mm.resize(10);
  EXPECT_EQ(tracker.Process(f, {}).status().code(), StatusCode::kInvalidArgument);
  f.depth_mm.assign(32 * 24, 1000);
  f.intrinsics.fx = 0;
  EXPECT_EQ(tracker.Process(f, {}).status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace arref
