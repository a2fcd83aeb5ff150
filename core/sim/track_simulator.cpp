#include "arref/sim/track_simulator.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "arref/fusion/raycaster.h"
#include "arref/track/model_caster.h"
#include "scene_builder.h"

namespace arref::sim {
namespace {

constexpr double kAhatWrapM = 1.0;     // AHAT's phase wraps about here (HoloLens 2 AHAT depth wraps beyond about 1 m)
constexpr double kAhatMaxRangeM = 3.0;

// Independent random streams of one simulation: adding draws to one leaves the others alone.
enum Stream : std::uint64_t { kKnots = 1, kLayout, kWorld, kDrift, kJump, kNoise, kNetwork, kStamps, kFlying };
std::mt19937_64 StreamRng(std::uint64_t seed, Stream s) {
  std::seed_seq seq{seed, static_cast<std::uint64_t>(s), std::uint64_t{0x7472616b}};
  return std::mt19937_64(seq);
}

}  // namespace

const char* FrameKindName(FrameKind kind) { return kind == FrameKind::kAhat ? "ahat" : "long-throw"; }

Result<FrameKind> ParseFrameKind(const std::string& name) {
  if (name == "long-throw") return FrameKind::kLongThrow;
  if (name == "ahat") return FrameKind::kAhat;
  return Status::InvalidArgument("frame kind '" + name + "' (known: long-throw, ahat)");
}

struct TrackSimulator::Impl {
  std::shared_ptr<const RobotModel> robot;
  TrackSimOptions o;
  std::uint64_t seed = 0;
  std::vector<JointInfo> joints;
  std::vector<std::vector<double>> knots;  // [knot][joint]
  CellScene cell;
  RayCaster props;
  ModelCaster robot_caster;
  DepthIntrinsics intrinsics;
  double max_range_m = 5.0;
  Iso3 T_world0_cell = Iso3::Identity();
  Iso3 drift = Iso3::Identity();  // T_world_world0: drift and the jump so far
  Iso3 jump = Iso3::Identity();
  double jump_time_s = std::numeric_limits<double>::infinity();
  int frames = 0, next = 0;
  std::mt19937_64 drift_rng, noise_rng, network_rng, flying_rng;

  double FrameTime(int i) const { return i / o.fps; }
  JointValues Joints(double t) const;
  Iso3 T_cell_camera(double t) const;
  std::vector<double> WithFlyingPixels(const std::vector<double>& z);
};

// A time-of-flight pixel whose footprint straddles a depth edge sums the returns of both
// surfaces and reads a depth between them: for each pixel on an edge (its 4-neighbour with the
// largest step, where both have a return), with probability flying_pixel_rate, a depth drawn
// uniformly between the two.
std::vector<double> TrackSimulator::Impl::WithFlyingPixels(const std::vector<double>& z) {
  const int w = intrinsics.width, h = intrinsics.height;
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  std::vector<double> out = z;
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const std::size_t p = static_cast<std::size_t>(v) * w + u;
      if (z[p] <= 0) continue;
      double step = 0.0;
      for (const auto& [du, dv] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
        const int nu = u + du, nv = v + dv;
        if (nu < 0 || nv < 0 || nu >= w || nv >= h) continue;
        const double zn = z[static_cast<std::size_t>(nv) * w + nu];
        if (zn > 0 && std::abs(zn - z[p]) > std::abs(step)) step = zn - z[p];
      }
      if (std::abs(step) > o.flying_edge_m && u01(flying_rng) < o.flying_pixel_rate) out[p] = z[p] + u01(flying_rng) * step;
    }
  return out;
}

JointValues TrackSimulator::Impl::Joints(double t) const {
  const double k = std::clamp(t / o.knot_interval_s, 0.0, static_cast<double>(knots.size() - 1) - 1e-9);
  const std::size_t a = static_cast<std::size_t>(k);
  const double u = k - static_cast<double>(a), w = u * u * (3 - 2 * u);  // zero velocity at both knots
  JointValues out;
  for (std::size_t j = 0; j < joints.size(); ++j)
    out[joints[j].name] = knots[a][j] + w * (knots[a + 1][j] - knots[a][j]);
  return out;
}

Iso3 TrackSimulator::Impl::T_cell_camera(double t) const {
  const double radius = o.walk_radius_m, arc = o.walk_arc_deg * kDegree;
  const double length = radius * arc, walked = std::fmod(o.walk_speed_m_s * t, 2 * length);
  const double along = walked < length ? walked : 2 * length - walked;  // back and forth
  const double azimuth = -0.5 * arc + along / radius;
  const Vec3 base = cell.T_cell_base.translation();
  const Vec3 eye = base + Vec3(radius * std::cos(azimuth), radius * std::sin(azimuth),
                               o.eye_height_m - base.z() + 0.02 * std::sin(2 * std::numbers::pi * 1.8 * t));
  const Vec3 target = base + Vec3(0, 0, 0.6);
  Iso3 T = LookAt(eye, target);
  // A head does not stare at one point: slow yaw and pitch about the gaze.
  const double wander = o.head_wander_deg * kDegree;
  T.rotate(Eigen::AngleAxisd(wander * std::sin(0.7 * t), Vec3::UnitY()));
  T.rotate(Eigen::AngleAxisd(0.6 * wander * std::sin(1.3 * t + 1.0), Vec3::UnitX()));
  return T;
}

TrackSimulator::TrackSimulator(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TrackSimulator::TrackSimulator(TrackSimulator&&) noexcept = default;
TrackSimulator& TrackSimulator::operator=(TrackSimulator&&) noexcept = default;
TrackSimulator::~TrackSimulator() = default;

Result<TrackSimulator> TrackSimulator::Create(std::shared_ptr<const RobotModel> robot, const TrackSimOptions& options,
                                              std::uint64_t rng_seed) {
  if (!robot) return Status::InvalidArgument("track simulator: no robot");
  TrackSimOptions o = options;
  const bool ahat = o.kind == FrameKind::kAhat;
  if (o.fps <= 0) o.fps = ahat ? 45.0 : 30.0;
  if (o.walk_radius_m <= 0) o.walk_radius_m = ahat ? 1.2 : 1.9;
  if (o.depth_noise_fraction <= 0) o.depth_noise_fraction = ahat ? 0.003 : 0.01;
  if (o.depth_noise_floor_m <= 0) o.depth_noise_floor_m = ahat ? 0.002 : 0.0;
  if (!(o.duration_s > 0) || !(o.knot_interval_s > 0) || !(o.max_joint_speed_rad_s > 0) || !(o.joint_rate_hz > 0))
    return Status::InvalidArgument("track simulator: duration, knot interval, joint speed and rate must be > 0");
  if (o.jump_at_s < 0) o.jump_at_s = 0.5 * o.duration_s;
  if (!(o.flying_pixel_rate >= 0 && o.flying_pixel_rate <= 1) || !(o.flying_edge_m > 0))
    return Status::InvalidArgument(fmt::format("track simulator: flying pixel rate {} is outside [0, 1] or edge {} m is not > 0",
                                               o.flying_pixel_rate, o.flying_edge_m));
  if (!(std::abs(o.pose_latency_s) <= 1.0))
    return Status::InvalidArgument(fmt::format("track simulator: pose latency {} s is outside [-1, 1] s", o.pose_latency_s));

  ARREF_ASSIGN_OR_RETURN(ModelCaster caster, ModelCaster::Create(*robot));
  CellOptions cell_options = o.cell;
  cell_options.robot_present = false;  // the robot is cast per frame, posed at its time
  ScanOptions scan;
  scan.path_radius_m = o.walk_radius_m;
  std::mt19937_64 layout_rng = StreamRng(rng_seed, kLayout);
  ARREF_ASSIGN_OR_RETURN(CellScene cell, BuildCellScene(*robot, cell_options, scan, layout_rng));
  ARREF_ASSIGN_OR_RETURN(RayCaster props, RayCaster::Create(cell.mesh));

  auto impl = std::make_unique<Impl>(Impl{robot, o, rng_seed, robot->ActuatedJoints(), {}, std::move(cell),
                                          std::move(props), std::move(caster)});
  Impl& I = *impl;
  // Joint targets: each step slow enough that the smoothstep's peak speed (1.5 x mean) stays
  // within max_joint_speed.
  std::mt19937_64 knot_rng = StreamRng(rng_seed, kKnots);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  const double max_step = o.max_joint_speed_rad_s * o.knot_interval_s / 1.5;
  const int knot_count = static_cast<int>(std::ceil(o.duration_s / o.knot_interval_s)) + 2;
  std::vector<double> q(I.joints.size(), 0.0);
  for (std::size_t j = 0; j < I.joints.size(); ++j)
    if (I.joints[j].has_limits) q[j] = std::clamp(0.0, I.joints[j].lower, I.joints[j].upper);
  for (int k = 0; k < knot_count; ++k) {
    I.knots.push_back(q);
    for (std::size_t j = 0; j < q.size(); ++j) {
      const JointInfo& info = I.joints[j];
      double lo = -o.joint_range_rad, hi = o.joint_range_rad;
      if (info.type == JointType::kPrismatic) lo = hi = 0.0;  // a gripper's fingers stay put
      if (info.has_limits) lo = std::max(lo, info.lower), hi = std::min(hi, info.upper);
      q[j] = std::clamp(q[j] + max_step * unit(knot_rng), lo, std::max(lo, hi));
    }
  }
  I.intrinsics = ahat ? DepthIntrinsics::FromFov(512, 512, 90.0) : DepthIntrinsics::FromFov(320, 288, 75.0);
  I.max_range_m = ahat ? kAhatMaxRangeM : 5.0;
  std::mt19937_64 world_rng = StreamRng(rng_seed, kWorld);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  I.T_world0_cell = MakeYawPose(4 * u01(world_rng) - 2, 4 * u01(world_rng) - 2, -1.0 - 0.5 * u01(world_rng),
                                2 * std::numbers::pi * u01(world_rng));
  std::mt19937_64 jump_rng = StreamRng(rng_seed, kJump);
  const double jump_m = o.jump_min_m + (o.jump_max_m - o.jump_min_m) * u01(jump_rng);
  const double jump_deg = (o.jump_min_deg + (o.jump_max_deg - o.jump_min_deg) * u01(jump_rng)) * (u01(jump_rng) < 0.5 ? -1 : 1);
  const double heading = 2 * std::numbers::pi * u01(jump_rng);
  // Re-localisation moves the world mostly sideways, a little up or down.
  const Vec3 dir = Vec3(std::cos(heading), std::sin(heading), 0.3 * (2 * u01(jump_rng) - 1)).normalized();
  // About the wearer's head (where the headset re-anchors), not the world's origin.
  const Vec3 pivot = I.T_world0_cell * I.T_cell_camera(o.jump_at_s).translation();
  I.jump = Eigen::Translation3d(pivot + jump_m * dir) * Eigen::AngleAxisd(jump_deg * kDegree, Vec3::UnitZ()) *
           Eigen::Translation3d(-pivot);
  I.jump_time_s = o.jump_at_s;
  I.frames = static_cast<int>(std::floor(o.duration_s * o.fps));
  I.drift_rng = StreamRng(rng_seed, kDrift);
  I.noise_rng = StreamRng(rng_seed, kNoise);
  I.network_rng = StreamRng(rng_seed, kNetwork);
  I.flying_rng = StreamRng(rng_seed, kFlying);
  spdlog::debug("track sim: {} frames of {}, jump {:.2f} m {:.1f} deg at {:.1f} s", I.frames, FrameKindName(o.kind),
                jump_m, jump_deg, o.jump_at_s);
  return TrackSimulator(std::move(impl));
}

const TrackSimOptions& TrackSimulator::options() const { return impl_->o; }
int TrackSimulator::frame_count() const { return impl_->frames; }
double TrackSimulator::jump_time_s() const { return impl_->jump_time_s; }
JointValues TrackSimulator::JointsAt(double t_s) const { return impl_->Joints(t_s); }
Iso3 TrackSimulator::T_world_base_initial() const { return impl_->T_world0_cell * impl_->cell.T_cell_base; }

Iso3 TrackSimulator::T_world_base_guess() const {
  std::mt19937_64 rng(impl_->seed ^ 0x5EEDull);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  return T_world_base_initial() * MakeYawPose(0.04 * u(rng), 0.04 * u(rng), 0.02 * u(rng), 4 * kDegree * u(rng));
}

Result<SimFrame> TrackSimulator::Next() {
  Impl& I = *impl_;
  if (I.next >= I.frames) return Status::FailedPrecondition("track simulator: the stream has ended");
  const int i = I.next++;
  const double t = I.FrameTime(i), dt = 1.0 / I.o.fps;
  // Drift since the last frame, then the jump when its time has come.
  if (i > 0) {
    std::normal_distribution<double> n(0.0, 1.0);
    const double sm = I.o.drift_m_per_sqrt_s * std::sqrt(dt), sr = I.o.drift_deg_per_sqrt_s * kDegree * std::sqrt(dt);
    const Iso3 step = MakeYawPose(sm * n(I.drift_rng), sm * n(I.drift_rng), sm * n(I.drift_rng), sr * n(I.drift_rng));
    I.drift = step * I.drift;
    if (t >= I.jump_time_s && I.FrameTime(i - 1) < I.jump_time_s) I.drift = I.jump * I.drift;
  }
  SimFrame out;
  out.true_time_s = t;
  out.after_jump = t >= I.jump_time_s;
  out.joints_true = I.Joints(t);
  ARREF_RETURN_IF_ERROR(I.robot_caster.Pose(*I.robot, out.joints_true));
  const Iso3 T_cell_cam = I.T_cell_camera(t);
  const DepthIntrinsics& c = I.intrinsics;
  PinholeCamera pinhole;  // the same camera for the props' caster
  pinhole.width = c.width, pinhole.height = c.height, pinhole.focal_px = c.fx;
  const RangeImage props = I.props.Render(pinhole, T_cell_cam, I.max_range_m);
  const ModelView robot = I.robot_caster.Render(c, I.cell.T_cell_base.inverse() * T_cell_cam, I.max_range_m, 1);
  DepthFrame& f = out.frame;
  f.time_s = t;
  f.intrinsics = c;
  f.wrap_m = I.o.kind == FrameKind::kAhat ? kAhatWrapM : 0.0;
  f.depth_mm.assign(static_cast<std::size_t>(c.width) * c.height, 0);
  std::vector<double> z_true(f.depth_mm.size(), 0.0);
  std::size_t robot_pixels = 0, robot_seen = 0;
  for (int v = 0; v < c.height; ++v)
    for (int u = 0; u < c.width; ++u) {
      const std::size_t p = static_cast<std::size_t>(v) * c.width + u;
      double z = props[p] > 0 ? props[p] / c.Ray(u, v).norm() : 0.0;
      if (robot.z_depth[p] > 0) {
        ++robot_pixels;
        if (z <= 0 || robot.z_depth[p] < z) z = robot.z_depth[p], ++robot_seen;
      }
      z_true[p] = z;
    }
  out.robot_visible_fraction = robot_pixels > 0 ? static_cast<double>(robot_seen) / static_cast<double>(robot_pixels) : 0.0;
  // Flying pixels draw from their own stream, so the noise and dropouts of a frame stay the same
  // with them or without.
  const std::vector<double> z_seen = I.o.flying_pixel_rate > 0 ? I.WithFlyingPixels(z_true) : std::move(z_true);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  for (std::size_t p = 0; p < z_seen.size(); ++p) {
    double z = z_seen[p];
    if (z <= 0 || u01(I.noise_rng) < I.o.dropout) continue;
    z += (I.o.depth_noise_fraction * z + I.o.depth_noise_floor_m) * noise(I.noise_rng);
    if (f.wrap_m > 0) z = std::fmod(z, f.wrap_m);
    f.depth_mm[p] = static_cast<std::uint16_t>(std::clamp(std::round(1000 * z), 0.0, 65535.0));
  }
  const Iso3 T_world_cell = I.drift * I.T_world0_cell;
  std::normal_distribution<double> jm(0.0, I.o.pose_jitter_m), jr(0.0, I.o.pose_jitter_deg * kDegree);
  const Vec3 axis_angle(jr(I.noise_rng), jr(I.noise_rng), jr(I.noise_rng));
  Iso3 jitter = Iso3::Identity();
  if (axis_angle.norm() > 0) jitter.linear() = Eigen::AngleAxisd(axis_angle.norm(), axis_angle.normalized()).toRotationMatrix();
  jitter.translation() = Vec3(jm(I.noise_rng), jm(I.noise_rng), jm(I.noise_rng));
  f.T_world_camera = T_world_cell * I.T_cell_camera(t + I.o.pose_latency_s) * jitter;
  out.T_world_base_true = T_world_cell * I.cell.T_cell_base;
  return out;
}

std::vector<SimJointSample> TrackSimulator::JointSamples(double t0_s, double t1_s) const {
  const Impl& I = *impl_;
  std::vector<SimJointSample> out;
  const double rate = I.o.joint_rate_hz;
  for (long k = static_cast<long>(std::floor(t0_s * rate)) + 1; k <= static_cast<long>(std::floor(t1_s * rate)); ++k) {
    const double t = static_cast<double>(k) / rate;
    if (t <= t0_s || t < 0) continue;
    // The stamp's jitter is a function of the sample alone, so any split of the stream agrees.
    std::seed_seq seq{I.seed, static_cast<std::uint64_t>(kStamps), static_cast<std::uint64_t>(k)};
    std::mt19937_64 rng(seq);
    // Within 0.4 of the spacing: a controller's stamps jitter but never run backwards.
    const double jitter = std::clamp(I.o.joint_stamp_jitter_s * std::normal_distribution<double>(0.0, 1.0)(rng),
                                     -0.4 / rate, 0.4 / rate);
    // The joints are those of the stamped instant: the stamp errs, not the robot.
    out.push_back({t + jitter + I.o.sender_clock_offset_s, I.Joints(t)});
  }
  return out;
}

ClockExchange TrackSimulator::RoundTrip(double true_time_s) {
  Impl& I = *impl_;
  std::exponential_distribution<double> delay(1.0 / std::max(1e-6, I.o.network_delay_mean_s));
  const double out_delay = 0.001 + delay(I.network_rng), back_delay = 0.001 + delay(I.network_rng);
  ClockExchange e;
  e.t0 = true_time_s + I.o.sender_clock_offset_s;
  e.t1 = true_time_s + out_delay;
  e.t2 = e.t1 + 0.0002;
  e.t3 = e.t2 + back_delay + I.o.sender_clock_offset_s;
  return e;
}

}  // namespace arref::sim
