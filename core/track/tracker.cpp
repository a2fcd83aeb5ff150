#include "arref/track/tracker.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <string_view>

#include "arref/base/clock.h"
#include "arref/icp/fast_icp.h"
#include "arref/scene/sampling.h"
#include "arref/track/camera_pose_history.h"
#include "arref/track/depth_noise.h"

namespace arref {

const char* TrackStateName(TrackState state) {
  switch (state) {
    case TrackState::kTracking: return "tracking";
    case TrackState::kRejected: return "rejected";
    case TrackState::kLost: return "lost";
    case TrackState::kReacquired: return "reacquired";
    case TrackState::kJump: return "jump";
    case TrackState::kNoRobot: return "no_robot";
  }
  return "?";
}

Status CheckDepthFrame(const DepthFrame& f) {
  if (!f.intrinsics.valid())
    return Status::InvalidArgument(fmt::format("depth frame: intrinsics {}x{} fx {} fy {} are not usable", f.intrinsics.width,
                                               f.intrinsics.height, f.intrinsics.fx, f.intrinsics.fy));
  const std::size_t n = static_cast<std::size_t>(f.intrinsics.width) * f.intrinsics.height;
  if (f.depth_mm.size() != n)
    return Status::InvalidArgument(fmt::format("depth frame: {} depth values for {}x{} pixels", f.depth_mm.size(),
                                               f.intrinsics.width, f.intrinsics.height));
  if (!f.T_world_camera.matrix().allFinite() || !std::isfinite(f.time_s))
    return Status::InvalidArgument("depth frame: the camera pose or the timestamp is not finite");
  if (!(f.wrap_m >= 0) || !std::isfinite(f.wrap_m)) return Status::InvalidArgument("depth frame: wrap_m must be >= 0");
  return Status::Ok();
}

namespace {


// One frame's registration from one starting pose.
struct Measurement {
  bool fits = false;
  Iso3 T_world_base = Iso3::Identity();
  Mat4 covariance = Mat4::Identity();
  double agreement = 0.0;
  double coverage = 0.0;  // agreeing pixels of all visible model pixels with a depth
  // What the tracker decides on: the agreement, or in a wrapped frame (where depth behind the
  // model may be an occluder aliased there) the coverage.
  double support = 0.0;
  // The coverage of the pixels whose depth can be read (agreeing, seen through or occluded; not
  // the ambiguous ones of a wrapped frame): the same as the coverage in an unwrapped frame.
  double readable = 0.0;
  double start_support = 0.0;  // the support of the pose the fit started from
  double start_agreement = 0.0, start_readable = 0.0;
  std::size_t start_agree = 0;  // agreeing pixels at the start pose
  // At the start pose the model is in view with depth, but hidden: no pixel agrees and none is
  // seen through (all occluded or ambiguous), so the frame says nothing about that pose.
  bool start_hidden = false;
  Iso3 T_world_base_start = Iso3::Identity();  // the pose the fit started from
  std::size_t model_points = 0, depth_points = 0;
  std::size_t agree = 0, through = 0, occluded = 0, ambiguous = 0, resolved = 0;  // pixel classes at the fit
};

// ICP's correspondence distances from a pose that may be far off (a seed, the camera's view).
const std::vector<double>& WideDistances() {
  static const std::vector<double> wide = {0.15, 0.06, 0.025};
  return wide;
}

// A sensor whose depth wraps (AHAT, modulo about 1 m): depth behind the model and an occluder
// in front of it can read alike, so some rules hold only for frames that do not wrap.
bool Wraps(const DepthFrame& f) { return f.wrap_m > 0; }

std::string Describe(const Measurement& m) {
  const Vec3 t = m.T_world_base.translation();
  return fmt::format("fits {} agreement {:.2f} coverage {:.2f} readable {:.2f} support {:.2f} (start {:.2f}{}), pixels: "
                     "{} agree, {} through ({} resolved), {} occluded, {} ambiguous; at ({:.3f}, {:.3f}, {:.3f})",
                     m.fits, m.agreement, m.coverage, m.readable, m.support, m.start_support,
                     m.start_hidden ? ", hidden" : "", m.agree, m.through, m.resolved, m.occluded, m.ambiguous, t.x(),
                     t.y(), t.z());
}

// A pose's measurement in the debug log, described only when it will be written: the tracker
// logs every pose it measures, on every frame.
void LogMeasurement(std::string_view what, const Measurement& m) {
  if (spdlog::should_log(spdlog::level::debug)) spdlog::debug("tracker: {}: {}", what, Describe(m));
}

}  // namespace

struct Tracker::Impl {
  std::shared_ptr<const RobotModel> robot;
  TrackerSettings settings;
  ModelCaster caster;
  PoseFilter filter;
  std::optional<Iso3> seed;
  // The last frame that fit: where its camera was and where the filter put the base.
  std::optional<Iso3> last_T_world_camera;
  std::optional<Iso3> last_T_world_base;
  std::optional<std::pair<double, Iso3>> previous_camera;  // the last frame's time and camera pose
  int lost_frames = 0;
  // A pose found while lost that has yet to explain confirm_frames frames clearly better than
  // the filter before it replaces it, filtered on its own.
  std::optional<PoseFilter> candidate;
  int candidate_frames = 0;
  // The bar the candidate must pass on each frame: clearly better than the filter (on the jump
  // view's coverage when it was found at the camera's view of a jump), or at least as good when
  // it is the camera's view challenging the filter while a jump is pending (see Process).
  enum class Bar { kClearlyBetter, kClearlyBetterJumpView, kAtLeastAsGood };
  Bar candidate_bar = Bar::kClearlyBetter;
  // A fit has been fused since the filter was last (re)started: its pose is then one the frames
  // have confirmed, not only a re-reference's.
  bool fused = false;
  // Where the robot is if the world moved with the camera at its last jump: the camera's step
  // across that frame applied to the filtered pose. It stays put in the new world, while a
  // guess from the last fitted frame's camera drifts off with the wearer's walk.
  std::optional<Iso3> jump_guess;
  // In a wrapped frame, the model as the filter places it, seen from this frame's camera (empty
  // when there is none): a depth behind another pose's model that the filter's model explains is
  // the robot seen through that pose, not an occluder aliased there.
  ModelView reference;
  double jump_time_s = 0.0;  // when jump_guess was set
  double camera_pose_latency_s = 0.0;  // SetCameraPoseLatency
  CameraPoseHistory reported_cameras;  // the frames' reported poses, when they come late
  bool Jumped(const std::pair<double, Iso3>& before, const DepthFrame& f) const;
  bool CameraJumped(const DepthFrame& f) const;
  const DepthFrame& AtExposure(const DepthFrame& f, std::optional<DepthFrame>* corrected);

  int StrideFor(const DepthIntrinsics& c) const {
    return settings.stride > 0 ? settings.stride : std::max(1, (c.width + 159) / 160);
  }
  ModelView RenderModel(const DepthFrame& f, const Iso3& T_world_base) const;
  Measurement Measure(const DepthFrame& f, const Iso3& T0, const std::vector<double>& distances, int iterations,
                      TrackResult* out, ModelView* view_out = nullptr) const;
  PointCloud DepthPoints(const DepthFrame& f, const ModelView& view, const Iso3& T_world_base, const Aabb& crop,
                         bool drop_occluders = false) const;
  // How far a depth may lie from the model's at a pixel and still agree with it (range z): the
  // camera-pose error and the sensor's noise, both growing with range. Nearer than that is an
  // occluder, farther the model is seen through.
  double Tolerance(double z) const { return settings.agree_m + settings.agree_range_fraction * noise_scale * z; }
  // Depth this close above the model's bottom is the floor: its noise, scaled as the tolerance's.
  double FloorClearance() const { return noise_scale * settings.floor_clearance_m; }
  // The depth's noise measured from the stream's frames over the sensor's the tolerance was set
  // for, at least 1 (TrackerSettings::reference_depth_noise): it scales the tolerance's range part
  // and the floor clearance.
  DepthNoiseEstimate depth_noise{settings.depth_noise_frames};
  double noise_scale = 1.0;
  // Wrapped frames' noise is measured and reported, not acted on: widening their tolerance with it
  // fused noisy fits of half-hidden arms and lost frames within 10 mm at 2 % and 3 % of range
  // (docs/tracking.md, "Wrapped depth's noise: measured, reported, not acted on").
  DepthNoiseEstimate wrapped_depth_noise{settings.depth_noise_frames};
  // An unwrapped frame is measured alone, before anything else, and scales the tolerance; a
  // wrapped one only where the filter's model says how far its readings are (filter_view: null
  // while there is no such view), and only reported.
  void MeasureDepthNoise(const DepthFrame& f, const ModelView* filter_view = nullptr);
  struct Agreement {
    double agreement = 0.0, coverage = 0.0, support = 0.0, readable = 0.0;
    std::size_t agree = 0, through = 0, occluded = 0, ambiguous = 0, resolved = 0;
  };
  // In a wrapped frame an ambiguous pixel whose depth `other` (another pose's model, seen from
  // this frame's camera) explains is the robot seen through this pose: counted as seen through.
  Agreement AgreementAt(const DepthFrame& f, const ModelView& view, const Iso3& T_world_base,
                        const ModelView* other = nullptr) const;
  bool ExplainedBy(const ModelView& other, const DepthFrame& f, int u, int v) const;
  // The camera's view at a jump is held to the coverage of its readable pixels: in a wrapped frame
  // an occluder near the camera reads, aliased, as depth behind a hidden arm (the KR5 arc's dev
  // stream 5 in AHAT frames: 6,000 of 9,000 visible model pixels), which says nothing about the
  // pose. (In an unwrapped frame the two coverages are the same.)
  bool Reacquires(const Measurement& m, bool jump_view = false) const {
    return m.agreement >= settings.min_reacquire_agreement &&
           (jump_view ? m.readable >= settings.min_jump_view_coverage && !Slid(m)
                      : m.coverage >= settings.min_reacquire_coverage);
  }
  // A fit from the camera's view that ended farther from it than ICP reaches from a start (twice
  // the widest tracking distance) or turned more than a search step slid along the props round a
  // hidden arm: head tracking's guess is off by its per-frame error only (0.3 deg and 4 mm per
  // axis), about 2 cm at the arm and under 4 cm in nine jumps of ten (docs/tracking.md, "The jump
  // from the camera's path"). Held-back draw 21's MH5 AHAT stream 0 took a fit 146 mm and 42 deg
  // from its start as the jump's pose, and held it for 2 s.
  bool Slid(const Measurement& m) const {
    const double moved_m = (m.T_world_base.translation() - m.T_world_base_start.translation()).norm();
    const double turned = std::abs(YawOf(m.T_world_base_start.inverse() * m.T_world_base));
    return moved_m > 2 * settings.icp_distances_m.front() || turned > settings.search_yaw_step_deg * kDegree;
  }
  // A fit explaining the frame clearly worse than its start (pulled off by depth that is not the
  // robot), or covering too little of the visible model to constrain every direction: not fused.
  bool Untrusted(const Measurement& m) const {
    return m.support < m.start_support - settings.max_fit_support_drop || m.coverage < settings.min_fuse_coverage;
  }
  Mat4 Covariance(const PointCloud& source, const TargetCloud& target, const Iso3& T_base_world) const;
  // A fit covering a share of the visible model weighs with that share to a power
  // (TrackerSettings::covariance_coverage_power).
  Mat4 CoverageWeighted(const Mat4& covariance, double coverage) const {
    return covariance / std::pow(std::max(coverage, settings.min_covariance_coverage), settings.covariance_coverage_power);
  }
  std::optional<Iso3> GridSearch(const DepthFrame& f, const std::vector<Iso3>& guesses, TrackResult* out) const;

  // Process, in the order it runs them on a frame.
  struct Step;
  void ExplainByFilter(Step& st);
  std::optional<TrackResult> ConfirmCandidate(Step& st);
  void ChallengeWithJumpView(Step& st);
  TrackResult TakeFit(Step& st);
  TrackResult Acquire(Step& st);
  void FusePartlySeen(Step& st);
  TrackResult Reacquire(Step& st);
  // ... and what those share.
  bool InGate(const Step& st, const Measurement& x) const;
  bool InGate(const Step& st, const Vec4& z, const Mat4& R) const;
  bool ClearlyBetter(const Step& st, const Measurement& x, bool jump_view = false) const;
  bool AtLeastAsGood(const Step& st, const Measurement& x) const;
  void StartCandidate(const Step& st, const Measurement& x, Bar bar, std::string_view how);
  std::optional<TrackResult> Found(Step& st, const Measurement& x, std::string_view how, bool jump_view = false);
  TrackResult AdoptCandidate(Step& st, const Measurement& c);
  TrackResult Restart(Step& st, const Measurement& m);
  TrackResult Finish(Step& st, TrackState state);
};

// Faster than a head moves: the headset's world moved under the camera (re-localisation).
bool Tracker::Impl::Jumped(const std::pair<double, Iso3>& before, const DepthFrame& f) const {
  const double dt = std::max(1e-3, f.time_s - before.first);
  const Iso3 delta = before.second.inverse() * f.T_world_camera;
  const double angle_deg = Eigen::AngleAxisd(delta.linear()).angle() / kDegree;
  return delta.translation().norm() / dt > settings.camera_jump_m_per_s || angle_deg / dt > settings.camera_jump_deg_per_s;
}

bool Tracker::Impl::CameraJumped(const DepthFrame& f) const { return previous_camera && Jumped(*previous_camera, f); }

void Tracker::Impl::MeasureDepthNoise(const DepthFrame& f, const ModelView* filter_view) {
  if (settings.reference_depth_noise <= 0) return;
  if (Wraps(f)) {
    if (!filter_view) return;
    if (const std::optional<double> noise = WrappedFrameDepthNoise(f, *filter_view)) wrapped_depth_noise.Add(*noise);
    return;
  }
  if (const std::optional<double> noise = FrameDepthNoise(f)) depth_noise.Add(*noise);
  if (const std::optional<double> noise = depth_noise.fraction())
    noise_scale = std::max(1.0, *noise / settings.reference_depth_noise);
}

// The frame with its camera at the exposure when the device stamps its pose late: the reported
// pose at frame time t - latency, interpolated from the frames before it (CameraPoseHistory).
// Reports before and after a camera jump (a re-localisation) lie in different worlds and are
// not blended: the first frame of a stream and the first after a jump keep their reported pose.
// (Taking the jump frame back by the camera's motion over the latency before the jump was
// measured and not kept: docs/tracking.md, "A late camera pose, declared".) A corrected frame is
// a copy (its depth too: tens of microseconds against the frame's milliseconds).
const DepthFrame& Tracker::Impl::AtExposure(const DepthFrame& f, std::optional<DepthFrame>* corrected) {
  if (camera_pose_latency_s <= 0) return f;
  if (const auto* newest = reported_cameras.newest(); newest && Jumped(*newest, f)) reported_cameras.Clear();
  reported_cameras.Add(f.time_s, f.T_world_camera);
  const std::optional<Iso3> T_world_camera = reported_cameras.At(f.time_s - camera_pose_latency_s);
  if (!T_world_camera) return f;
  corrected->emplace(f);
  (*corrected)->T_world_camera = *T_world_camera;
  return **corrected;
}

PointCloud Tracker::Impl::DepthPoints(const DepthFrame& f, const ModelView& view, const Iso3& T_world_base,
                                      const Aabb& crop, bool drop_occluders) const {
  const DepthIntrinsics& c = f.intrinsics;
  const int s = view.stride, gw = c.width / s, gh = c.height / s;
  const Eigen::Isometry3f T_base_camera = (T_world_base.inverse() * f.T_world_camera).cast<float>();
  const Eigen::Isometry3f T_world_camera = f.T_world_camera.cast<float>();
  PointCloud out;
  for (int gv = 0; gv < gh; ++gv)
    for (int gu = 0; gu < gw; ++gu) {
      float d = f.DepthAt(gu * s, gv * s);
      if (d <= 0) continue;
      const float expected = view.z_depth[static_cast<std::size_t>(gv) * gw + gu];
      if (Wraps(f)) {
        // Only where the model predicts a depth can a wrapped one be told apart.
        if (expected <= 0) continue;
        d = UnwrappedDepth(d, expected, f.wrap_m);
      }
      // An occluder, as AgreementAt counts one: depth in front of the model's own at this pixel
      // by more than the agreement's tolerance.
      if (drop_occluders && expected > 0 && d < expected - static_cast<float>(Tolerance(expected))) continue;
      const Vec3f p_cam = (c.Ray(gu * s, gv * s) * d).cast<float>();
      if (!crop.Contains(T_base_camera * p_cam)) continue;
      out.points.push_back(T_world_camera * p_cam);
    }
  return out;
}

// The fraction of the model's visible pixels whose depth agrees with the model moved to
// T_world_base, of those that agree or that the depth sees through (a depth nearer than the
// model is an occluder, and says nothing).
Tracker::Impl::Agreement Tracker::Impl::AgreementAt(const DepthFrame& f, const ModelView& view,
                                                    const Iso3& T_world_base, const ModelView* other) const {
  const DepthIntrinsics& c = f.intrinsics;
  const Eigen::Isometry3f T_camera_base = (f.T_world_camera.inverse() * T_world_base).cast<float>();
  std::size_t agree = 0, through = 0, occluded = 0, ambiguous = 0, resolved = 0;
  for (const Vec3f& p : view.points_base.points) {
    const Vec3f q = T_camera_base * p;
    if (q.z() <= 0.05f) continue;
    const int u = static_cast<int>(std::floor(c.fx * q.x() / q.z() + c.cx));
    const int v = static_cast<int>(std::floor(c.fy * q.y() / q.z() + c.cy));
    if (u < 0 || v < 0 || u >= c.width || v >= c.height) continue;
    const float d = UnwrappedDepth(f.DepthAt(u, v), q.z(), f.wrap_m);
    if (d <= 0) continue;
    const float tol = static_cast<float>(Tolerance(q.z()));
    if (std::abs(d - q.z()) < tol) ++agree;
    // A wrapping sensor cannot tell depth behind the model from an occluder more than half a
    // wrap in front of it (aliased behind): only when that nearer alias would lie behind the
    // camera is the model seen through.
    else if (d > q.z()) {
      if (!Wraps(f) || d - f.wrap_m <= 0) ++through;
      else if (other && ExplainedBy(*other, f, u, v)) ++through, ++resolved;
      else ++ambiguous;
    } else {
      ++occluded;
    }
  }
  Agreement a;
  a.agreement = agree + through ? static_cast<double>(agree) / static_cast<double>(agree + through) : 0.0;
  a.coverage = agree ? static_cast<double>(agree) / static_cast<double>(agree + through + occluded + ambiguous) : 0.0;
  a.readable = agree ? static_cast<double>(agree) / static_cast<double>(agree + through + occluded) : 0.0;
  a.support = Wraps(f) ? a.coverage : a.agreement;
  a.agree = agree, a.through = through, a.occluded = occluded, a.ambiguous = ambiguous, a.resolved = resolved;
  return a;
}

// Whether the depth at pixel (u, v) lies where the model of `other` has its surface (read at the
// alias nearest that model's depth there).
bool Tracker::Impl::ExplainedBy(const ModelView& other, const DepthFrame& f, int u, int v) const {
  if (other.z_depth.empty()) return false;
  const int s = other.stride, gw = other.width / s, gh = other.height / s;
  const int gu = std::clamp((u + s / 2) / s, 0, gw - 1), gv = std::clamp((v + s / 2) / s, 0, gh - 1);
  const float z = other.z_depth[static_cast<std::size_t>(gv) * gw + gu];
  if (z <= 0) return false;
  const float d = UnwrappedDepth(f.DepthAt(u, v), z, f.wrap_m);
  return d > 0 && std::abs(d - z) < Tolerance(z);
}

// ICP's 4-DoF covariance at the fit, mapped from its perturbation of T_base_world to the
// state (x, y, z, yaw) of T_world_base.
Mat4 Tracker::Impl::Covariance(const PointCloud& source, const TargetCloud& target, const Iso3& T_base_world) const {
  const Eigen::Isometry3f T = T_base_world.cast<float>();
  const float max_sq = static_cast<float>(settings.icp_distances_m.back() * settings.icp_distances_m.back());
  Mat4 H = Mat4::Zero();
  double sq = 0;
  std::size_t n = 0;
  for (const Vec3f& s : source.points) {
    const Vec3f p = T * s;
    std::uint32_t j;
    float d2;
    if (!target.index().NearestWithin(p, max_sq, &j, &d2)) continue;
    const Eigen::Vector3d nrm = target.normals()[j].cast<double>(), pd = p.cast<double>();
    const double r = nrm.dot(pd - target.index().points()[j].cast<double>());
    Vec4 J;
    J << nrm, pd.cross(nrm).z();
    H += J * J.transpose();
    sq += r * r;
    ++n;
  }
  if (n < 10) return Mat4::Identity();
  const double sigma2 = sq / static_cast<double>(n - 4);
  Mat4 cov_xi = settings.covariance_inflation * sigma2 * H.ldlt().solve(Mat4::Identity());
  // T_world_base exp(-xi): the translation turns by R_world_base, both change sign.
  Mat4 J = Mat4::Zero();
  J.topLeftCorner<3, 3>() = -T_base_world.linear().transpose();
  J(3, 3) = -1;
  Mat4 cov = J * cov_xi * J.transpose();
  return 0.5 * (cov + cov.transpose());
}

// A small or distant robot covers few pixels: traced at every pixel then, so that the fit
// keeps enough points to be constrained (MH5 at 1.2 m in AHAT frames had 230-280 at stride 3).
ModelView Tracker::Impl::RenderModel(const DepthFrame& f, const Iso3& T_world_base) const {
  const Iso3 T_base_camera = T_world_base.inverse() * f.T_world_camera;
  const int stride = StrideFor(f.intrinsics);
  ModelView view = caster.Render(f.intrinsics, T_base_camera, settings.max_range_m, stride);
  if (stride > 1 && view.points_base.size() < settings.dense_below_points)
    view = caster.Render(f.intrinsics, T_base_camera, settings.max_range_m, 1);
  return view;
}

Measurement Tracker::Impl::Measure(const DepthFrame& f, const Iso3& T0, const std::vector<double>& distances,
                                   int iterations, TrackResult* out, ModelView* view_out) const {
  Measurement m;
  m.T_world_base_start = T0;
  LapTimer lap;
  const ModelView view = RenderModel(f, T0);
  if (view_out) *view_out = view;
  m.model_points = view.points_base.size();
  // Another pose than the filter's is measured with its ambiguous pixels read against the filter's
  // model (Process sets `reference` once the filter's own measurements are done).
  const ModelView* other = reference.z_depth.empty() ? nullptr : &reference;
  const Agreement start = AgreementAt(f, view, T0, other);
  m.start_support = start.support;
  m.start_agreement = start.agreement, m.start_readable = start.readable;
  m.start_agree = start.agree;
  m.start_hidden = start.agree + start.through == 0 && start.occluded + start.ambiguous > 0;
  Aabb crop = view.bounds_base.Grown(static_cast<float>(settings.crop_margin_m));
  crop.min.z() = view.bounds_base.min.z() + static_cast<float>(FloorClearance());
  // Depth in front of the model by more than the agreement's tolerance is an occluder (at the
  // long-throw walk's far end 85-95 % of the visible model pixels), which only pulls the fit off;
  // the fit leaves out the pixels the agreement counts as occluded (until 2026-12-03 the bar was
  // the crop margin, 8 cm, which kept occluder depth 5-8 cm in front of the arm at 2 m range).
  // This rule and the two below hold for unwrapped (long-throw) frames only: in AHAT frames they
  // recovered the KR5 arc's lost stream but lost one of the SIA10D's (not yet understood;
  // docs/tracking.md).
  PointCloud source = DepthPoints(f, view, T0, crop, !Wraps(f));
  m.depth_points = source.size();
  out->model_ms += lap.Lap();
  if (m.model_points < settings.min_model_points || source.size() < settings.min_model_points) return m;
  source = Thinned(source, settings.max_source_points);
  const TargetCloud target(view.points_base);
  IcpSettings icp;
  icp.yaw_only = true;
  icp.max_iterations = iterations;
  icp.converged_cost_ratio = settings.icp_converged_cost_ratio;
  auto fit = AlignCoarseToFine(source, target, T0.inverse(), distances, icp);
  out->icp_ms += lap.Lap();
  if (!fit.ok() || fit->correspondences < settings.min_model_points / 2) return m;
  // The base stays gravity-aligned: 4-DoF steps keep roll and pitch as the prediction had them.
  m.T_world_base = StateToPose(PoseToState(fit->T_target_source.inverse()));
  const Agreement a = AgreementAt(f, view, m.T_world_base, other);
  m.agreement = a.agreement, m.coverage = a.coverage, m.support = a.support, m.readable = a.readable;
  m.agree = a.agree, m.through = a.through, m.occluded = a.occluded, m.ambiguous = a.ambiguous, m.resolved = a.resolved;
  m.covariance = Covariance(source, target, m.T_world_base.inverse());
  // ICP's covariance counts every depth point near a model point, an occluder's too; when only
  // a share of the visible model agrees with the depth, the robot's own pixels are that much
  // fewer, and a fit on them is less certain than that count says
  // (TrackerSettings::covariance_coverage_power).
  if (!Wraps(f)) m.covariance = CoverageWeighted(m.covariance, m.coverage);
  m.fits = m.support >= settings.min_agreement;
  out->icp_ms += lap.Lap();
  return m;
}

// Coarse ICP from a grid of poses round each guess, on the depth points round all of them;
// the poses holding the most depth points near the model are measured in full.
std::optional<Iso3> Tracker::Impl::GridSearch(const DepthFrame& f, const std::vector<Iso3>& guesses,
                                              TrackResult* out) const {
  struct Candidate { double inliers; Iso3 T; };
  std::vector<Candidate> candidates;
  const double reach = settings.search_step_m * settings.search_steps + 0.15;
  for (const Iso3& guess : guesses) {
    LapTimer lap;
    const ModelView view = RenderModel(f, guess);
    if (view.points_base.size() < settings.min_model_points) continue;
    Aabb crop = view.bounds_base.Grown(static_cast<float>(reach));
    crop.min.z() = view.bounds_base.min.z() + static_cast<float>(FloorClearance());
    const PointCloud all = DepthPoints(f, view, guess, crop);
    const PointCloud source = Thinned(all, settings.search_points);
    out->model_ms += lap.Lap();
    if (source.size() < settings.min_model_points) continue;
    const TargetCloud target(view.points_base);
    IcpSettings icp;
    icp.yaw_only = true;
    icp.max_iterations = 8;
    const Vec4 g = PoseToState(guess);
    for (int i = -settings.search_steps; i <= settings.search_steps; ++i)
      for (int j = -settings.search_steps; j <= settings.search_steps; ++j)
        for (int k = -settings.search_yaw_steps; k <= settings.search_yaw_steps; ++k) {
          const Iso3 T = StateToPose(g + Vec4(i * settings.search_step_m, j * settings.search_step_m, 0,
                                              k * settings.search_yaw_step_deg * kDegree));
          auto fit = AlignCoarseToFine(source, target, T.inverse(), {0.15, 0.06}, icp);
          ++out->hypotheses;
          if (!fit.ok()) continue;
          candidates.push_back({static_cast<double>(fit->correspondences), fit->T_target_source.inverse()});
        }
    out->icp_ms += lap.Lap();
  }
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) { return a.inliers > b.inliers; });
  std::optional<Iso3> best;
  double best_agreement = -1;
  for (std::size_t i = 0; i < std::min<std::size_t>(3, candidates.size()); ++i) {
    const Measurement m = Measure(f, StateToPose(PoseToState(candidates[i].T)), {0.06, 0.025}, settings.icp_iterations, out);
    if (spdlog::should_log(spdlog::level::debug)) LogMeasurement(fmt::format("search candidate {}", i), m);
    if (Reacquires(m) && m.support > best_agreement)
      best = m.T_world_base, best_agreement = m.support;
  }
  return best;
}

Tracker::Tracker(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Tracker::Tracker(Tracker&&) noexcept = default;
Tracker& Tracker::operator=(Tracker&&) noexcept = default;
Tracker::~Tracker() = default;

Result<Tracker> Tracker::Create(std::shared_ptr<const RobotModel> robot, TrackerSettings settings) {
  if (!robot) return Status::InvalidArgument("tracker: no robot");
  if (settings.icp_distances_m.empty()) return Status::InvalidArgument("tracker: icp_distances_m is empty");
  ARREF_ASSIGN_OR_RETURN(ModelCaster caster, ModelCaster::Create(*robot));
  auto impl = std::make_unique<Impl>(Impl{robot, settings, std::move(caster), PoseFilter(settings.filter), {}, {}, {}, {},
                                          0, {}, 0, {}});
  return Tracker(std::move(impl));
}

void Tracker::Seed(const Iso3& T_world_base) {
  impl_->seed = StateToPose(PoseToState(T_world_base));
  impl_->reported_cameras.Clear();
  impl_->filter.Clear();
  impl_->last_T_world_base.reset();
  impl_->last_T_world_camera.reset();
  impl_->candidate.reset();
  impl_->jump_guess.reset();
  impl_->fused = false;
}

Status Tracker::SetCameraPoseLatency(double latency_s) {
  if (!(latency_s >= 0.0 && latency_s <= CameraPoseHistory::kKeepS))
    return Status::InvalidArgument(
        fmt::format("tracker: camera pose latency {} s is outside [0, {}] s (a pose stamped before its exposure is not "
                    "supported)", latency_s, CameraPoseHistory::kKeepS));
  impl_->camera_pose_latency_s = latency_s;
  impl_->reported_cameras.Clear();
  return Status::Ok();
}

bool Tracker::seeded() const { return impl_->seed.has_value() || impl_->filter.initialised(); }
const TrackerSettings& Tracker::settings() const { return impl_->settings; }

// One frame's decision state: the filter's explanation of the frame, which the other poses
// measured in it (a candidate, the camera's view of a jump, a search's) are held against.
struct Tracker::Impl::Step {
  Step(const DepthFrame& f, bool camera_jumped) : frame(f), jumped(camera_jumped) {}
  const DepthFrame& frame;
  const SteadyClock::time_point start = SteadyClock::now();
  TrackResult out;
  bool jumped;                // the camera jumped into this frame
  bool tracking = false;      // the filter has a state
  bool jump_pending = false;  // this frame's camera jump, or one not yet re-referenced
  Iso3 predicted = Iso3::Identity();  // the filter's pose, or the seed
  Measurement m;              // the fit from `predicted`
  bool hidden = false;        // the filter's pose hidden, no jump pending: it holds
  // How well the filter explains this frame: at its pose, or by this frame's fit if it takes it;
  // and how little the frame contradicts it (its agreement), and its readable coverage.
  double explained = 0.0, explained_agreement = 0.0, explained_readable = 0.0;
  std::size_t explained_agree = 0;  // and on how many pixels it agrees with the depth
  // The agreement of the camera's view at a pending jump, once measured in this frame (1 when
  // hidden, as for the filter).
  std::optional<double> jump_view_agreement;
  bool candidate_measured = false;
  std::optional<Measurement> pending_view;  // the camera's view of a pending jump, when measured
};

TrackResult Tracker::Impl::Finish(Step& st, TrackState state) {
  TrackResult& out = st.out;
  out.state = state;
  if (filter.initialised()) {
    out.T_world_base = StateToPose(filter.state());
    out.covariance = filter.CovarianceAt(st.frame.time_s);
  } else if (seed) {
    out.T_world_base = *seed;
  }
  if (state == TrackState::kTracking || state == TrackState::kReacquired || state == TrackState::kJump) {
    last_T_world_base = out.T_world_base;
    last_T_world_camera = st.frame.T_world_camera;
    lost_frames = 0;
  }
  if (state == TrackState::kReacquired || state == TrackState::kJump) candidate.reset(), jump_guess.reset();
  reference = ModelView();
  previous_camera = {st.frame.time_s, st.frame.T_world_camera};
  out.depth_noise_fraction = (Wraps(st.frame) ? wrapped_depth_noise : depth_noise).fraction().value_or(0.0);
  out.total_ms = MsSince(st.start);
  return out;
}

TrackResult Tracker::Impl::Restart(Step& st, const Measurement& m) {
  filter.Reset(PoseToState(m.T_world_base), m.covariance, st.frame.time_s);
  fused = false;
  st.out.T_world_base_measured = m.T_world_base;
  st.out.agreement = m.support;
  return Finish(st, TrackState::kReacquired);
}

// Measures the filter's pose (or the seed) in the frame and how well the filter explains it.
void Tracker::Impl::ExplainByFilter(Step& st) {
  const DepthFrame& frame = st.frame;
  const TrackerSettings& s = settings;
  st.tracking = filter.initialised();
  st.predicted = st.tracking ? StateToPose(filter.state()) : *seed;
  ++st.out.hypotheses;
  // A world jump is pending from a camera jump (this frame's, or one not yet re-referenced): the
  // filter's pose is then known to be stale.
  st.jump_pending = st.jumped || jump_guess.has_value();
  ModelView filter_view;
  st.m = Measure(frame, st.predicted, st.tracking ? s.icp_distances_m : WideDistances(), s.icp_iterations, &st.out,
                 st.tracking && Wraps(frame) && !st.jump_pending ? &filter_view : nullptr);
  if (Wraps(frame) && !filter_view.z_depth.empty()) MeasureDepthNoise(frame, &filter_view);
  const Measurement& m = st.m;
  st.out.model_points = m.model_points, st.out.depth_points = m.depth_points, st.out.agreement = m.support;
  LogMeasurement("fit", m);
  st.explained = m.start_support;
  st.explained_agreement = m.start_agreement, st.explained_readable = m.start_readable;
  st.explained_agree = m.start_agree;
  // The filter's pose hidden (every visible model pixel occluded, or ambiguous in a wrapped
  // frame) with no camera jump pending: nothing in the frame speaks against it, so it explains
  // the frame as well as any pose can, and holds. Its support (0) would hand the frame to any
  // pose laid on the occluder: the MH5's dev stream 3 in AHAT frames, 4.9-6 s (the arm 97 %
  // hidden, a search pose 0.3 m off agreeing with 3,200 pixels of the occluder), and the
  // SIA10D's held-out stream 0 in long-throw frames, 8.5-8.8 s (the arm wholly behind a prop
  // for 0.3 s, a search pose 1.14 m off taken, never left: 231 of 330 frames within 10 mm).
  st.hidden = st.tracking && !st.jump_pending && m.start_hidden;
  if (st.hidden) st.explained = 1.0, st.explained_agreement = 1.0;
  auto take = [&](const Measurement& x) {
    st.explained = std::max(st.explained, x.support);
    st.explained_agreement = std::max(st.explained_agreement, x.agreement);
    st.explained_readable = std::max(st.explained_readable, x.readable);
    st.explained_agree = std::max(st.explained_agree, x.agree);
  };
  if (st.tracking && InGate(st, m)) {
    take(m);
  } else if (st.tracking && st.explained < 1.0) {
    // The fit left the filter's basin (or failed): the filter's pose refined locally, so that the
    // frame's own camera-pose error (which shifts a thin arm's silhouette by pixels) counts
    // against neither side.
    ++st.out.hypotheses;
    const Measurement local = Measure(frame, st.predicted, {s.icp_distances_m.back()}, s.icp_iterations, &st.out);
    if (InGate(st, local)) take(local);
    LogMeasurement("local", local);
  }
  st.out.agreement_filtered = st.explained;
  // In a wrapped frame every other pose is measured against the filter's model from here on
  // (not when a jump is pending: the filter's model then stands where the robot was).
  reference = std::move(filter_view);
}

bool Tracker::Impl::InGate(const Step& st, const Measurement& x) const {
  return x.fits && InGate(st, PoseToState(x.T_world_base), x.covariance);
}

bool Tracker::Impl::InGate(const Step& st, const Vec4& z, const Mat4& R) const {
  return filter.Mahalanobis2(z, R, st.frame.time_s) <= settings.filter.gate_chi2;
}

bool Tracker::Impl::ClearlyBetter(const Step& st, const Measurement& x, bool jump_view) const {
  if (!Reacquires(x, jump_view)) return false;
  if (Wraps(st.frame)) {
    // Coverage counts occluded pixels against a pose, so a pose found by search wins wherever
    // more of the scene looks like the robot than of the robot is in view: the MH5's dev
    // stream 3 (the arm 50-97 % behind a prop; search poses 0.2-0.3 m off laid on the prop
    // covered 0.6-0.8 against the true pose's 0.02-0.47, which nothing saw through). So in a
    // wrapped frame a pose found by search must also be contradicted (seen through, with its
    // ambiguous pixels read against the filter's model) no more than the pose the tracker
    // already has: the filter's; strictly less once a fit has been fused since the filter's
    // last (re)start (a pose only a re-reference gave, such as a camera's view 10 cm off in
    // the built-in robot's dev stream 1, keeps no such tie); and at a pending jump strictly
    // less than the camera's view (head tracking's guess, 1 when hidden).
    const bool beats_filter = fused ? x.agreement > st.explained_agreement : x.agreement >= st.explained_agreement;
    if (!jump_view && !st.jump_pending && !beats_filter) return false;
    if (!jump_view && st.jump_view_agreement && !(x.agreement > *st.jump_view_agreement)) return false;
    // The camera's view at a jump is compared on its readable coverage, as its bar (Reacquires).
    if (jump_view) return x.readable >= st.explained_readable + settings.rereference_margin;
  }
  return x.support >= st.explained + settings.rereference_margin;
}

// At a pending jump the camera's view needs only to explain the frame as well as the filter's
// explanation: head tracking moved the camera faster than a head moves, which is itself the
// evidence that the world moved with it. But it must fit: ICP from the camera's view of an arm
// all but hidden slides along the props, and the SIA10D's dev stream 5 in AHAT frames (0.31 m
// jump, 6-16 % of the arm readable) took such a slid pose 0.4 m off when ties were enough.
//
// In a wrapped frame shares alone can mislead: a pose with few readable pixels reads a high
// share on them. The held-back SIA10D AHAT stream 1 of --rng-seed 12 (a 0.55 m jump): the
// camera's view (3,036 agreeing pixels, readable share 0.85) was held to the stale pose's
// readable share and lost, while the stale pose's fits slid 0.69 m onto a pose with most of the
// arm out of view (1,116 agreeing pixels, share 0.94); three of them made the filter's own jump
// there, and the stream never came back (225 of 495 frames). So a view that agrees on at least
// as many pixels as the filter's explanation, and is contradicted no more, is as good too.
bool Tracker::Impl::AtLeastAsGood(const Step& st, const Measurement& x) const {
  if (!x.fits || !Reacquires(x, true)) return false;
  if (Wraps(st.frame))
    return x.agreement >= st.explained_agreement &&
           (x.readable >= st.explained_readable || x.agree >= st.explained_agree);
  return x.support >= st.explained;
}

TrackResult Tracker::Impl::AdoptCandidate(Step& st, const Measurement& c) {
  filter = std::move(*candidate);
  fused = false;
  candidate.reset();
  seed.reset();
  st.out.T_world_base_measured = c.T_world_base;
  st.out.agreement = c.support;
  return Finish(st, TrackState::kReacquired);
}

void Tracker::Impl::StartCandidate(const Step& st, const Measurement& x, Bar bar, std::string_view how) {
  candidate = PoseFilter(settings.filter);
  candidate->Reset(PoseToState(x.T_world_base), x.covariance, st.frame.time_s);
  candidate_frames = 1;
  candidate_bar = bar;
  spdlog::info("tracker: candidate {}, {:.3f} m from the filter's pose{}, agreeing {:.2f} against {:.2f}", how,
               (x.T_world_base.translation() - st.predicted.translation()).norm(),
               st.jumped ? " (the camera jumped)" : "", x.support, st.explained);
}

// A pose found on an earlier frame stays a candidate while it explains each frame clearly
// better than the filter, and replaces the filter after confirm_frames such frames.
std::optional<TrackResult> Tracker::Impl::ConfirmCandidate(Step& st) {
  st.candidate_measured = candidate.has_value();
  if (!candidate) return std::nullopt;
  const TrackerSettings& s = settings;
  ++st.out.hypotheses;
  const Measurement c = Measure(st.frame, StateToPose(candidate->state()), s.icp_distances_m, s.icp_iterations, &st.out);
  LogMeasurement("candidate", c);
  const bool holds = candidate_bar == Bar::kAtLeastAsGood ? AtLeastAsGood(st, c)
                                                          : ClearlyBetter(st, c, candidate_bar == Bar::kClearlyBetterJumpView);
  const FilterVerdict verdict =
      holds ? candidate->Update(PoseToState(c.T_world_base), c.covariance, st.frame.time_s, false) : FilterVerdict::kRejected;
  if (verdict == FilterVerdict::kAccepted) {
    if (++candidate_frames >= s.confirm_frames) {
      spdlog::info("tracker: re-referenced after {} frames agreeing {:.2f} against the filter's {:.2f}", candidate_frames,
                   c.support, st.explained);
      return AdoptCandidate(st, c);
    }
  } else {
    spdlog::debug("tracker: candidate dropped after {} frames: {}", candidate_frames,
                  holds ? "its fit left its own gate" : "it no longer explains the frame better than the filter");
    candidate.reset();
  }
  return std::nullopt;
}

// A camera jump sets the jump guess. The filter's stale pose can go on explaining the frames
// after a jump as well as the camera's view does where little of the arm shows, and it then
// holds while it fits: the MH5's long-throw stream of the held-back look at --rng-seed 5 (a
// 1.04 m jump; the stale pose agreed 0.78-1.00 at coverage 0.23-0.38 for 2.2 s, the camera's view
// 0.93 at 0.33). So while a jump is pending the camera's view is measured on each frame, for
// jump_challenge_s, and becomes a candidate when it explains the frame at least as well as the
// filter. Reacquire starts from the same view with the same distances: it reuses this.
void Tracker::Impl::ChallengeWithJumpView(Step& st) {
  const TrackerSettings& s = settings;
  if (st.jumped && st.tracking && previous_camera) {
    jump_guess = StateToPose(PoseToState(st.frame.T_world_camera * previous_camera->second.inverse() * st.predicted));
    jump_time_s = st.frame.time_s;
  }
  if (!st.tracking || !jump_guess || st.candidate_measured || st.frame.time_s - jump_time_s > s.jump_challenge_s) return;
  ++st.out.hypotheses;
  st.pending_view = Measure(st.frame, *jump_guess, s.icp_distances_m, s.icp_iterations, &st.out);
  LogMeasurement("the camera's view of a pending jump", *st.pending_view);
  if (AtLeastAsGood(st, *st.pending_view))
    StartCandidate(st, *st.pending_view, Bar::kAtLeastAsGood, "from the camera's view of a pending jump");
}

// The filter's pose fit: the first fit restarts the filter, later ones go through its gate.
TrackResult Tracker::Impl::TakeFit(Step& st) {
  const Measurement& m = st.m;
  st.out.T_world_base_measured = m.T_world_base;
  if (!st.tracking) return Acquire(st);
  // Two long-throw fits within the gate are not fused; the pose holds. One that explains the
  // frame worse than the pose it started from was pulled off by depth that is not the robot
  // (clutter inside the crop: at the long-throw walk's far end such fits ended 40-220 mm away
  // from a start 4-9 mm off, and walked the filter 10-32 mm off); a fit from a right start
  // explains the frame at least as well as its start, up to a few silhouette pixels
  // (max_fit_support_drop). And one on a few unhidden pixels errs the same way frame after
  // frame (min_fuse_coverage). Outside the gate nothing changes: such a fit is no evidence of
  // a jump either (not clearly better: worse than its start, or covering too little).
  if (!Wraps(st.frame) && Untrusted(m) && InGate(st, m)) return Finish(st, TrackState::kTracking);
  // Rejected measurements become a world jump only while they explain the frames clearly better.
  const FilterVerdict v = filter.Update(PoseToState(m.T_world_base), m.covariance, st.frame.time_s, ClearlyBetter(st, m));
  fused = v == FilterVerdict::kAccepted || (fused && v == FilterVerdict::kRejected);
  return Finish(st, v == FilterVerdict::kRejected ? TrackState::kRejected
                    : v == FilterVerdict::kJump   ? TrackState::kJump
                                                  : TrackState::kTracking);
}

// In a wrapped frame a fit's support is its coverage, and an arm half behind props (or half in
// depth the wrap makes ambiguous) covers under min_agreement however right the fit: held-back
// draw 25's SIA10D AHAT stream 1 after its jump, 5 s of fits agreeing 1.00 on 74-80 % of their
// readable pixels but covering 0.46-0.51, all dropped, while the wearer's world drifted the held
// pose from 9 to 13 mm off (439 of 495 frames within 10 mm). Such a fit from the filter's pose,
// within its gate and not slid, is fused as long-throw fits are, weighing with the cube of its
// coverage, and confirms the pose (`fused`: a search pose must then be seen through strictly
// less); the tracker stays lost meanwhile and searches on. Slid: fits turned 23 deg, agreeing
// on the MH5's unhidden half, walked its dev stream 1 from 7 to 11 mm off. Readable share:
// min_partial_fit_readable (TrackerSettings) says why it is not the fit bar's 0.6, and
// min_partial_fit_coverage why such a fit must cover more than a long-throw fit.
void Tracker::Impl::FusePartlySeen(Step& st) {
  const Measurement& m = st.m;
  const TrackerSettings& s = settings;
  if (!Wraps(st.frame) || !st.tracking || st.jump_pending) return;
  if (m.agreement < s.min_reacquire_agreement || m.readable < s.min_partial_fit_readable ||
      m.coverage < s.min_partial_fit_coverage || Untrusted(m) || Slid(m))
    return;
  const Mat4 R = CoverageWeighted(m.covariance, m.coverage);
  const Vec4 z = PoseToState(m.T_world_base);
  // The gate first, though Update gates too: a rejected update that is no jump evidence ends the
  // filter's run of rejected measurements, and a fit that is not even a fit must not end a jump's.
  if (!InGate(st, z, R) || filter.Update(z, R, st.frame.time_s, false) != FilterVerdict::kAccepted) return;
  st.out.T_world_base_measured = m.T_world_base;
  fused = true;
}

// The first fit: the best of the seed's and of its heading turned by the search's yaw steps.
// From a seed 4 deg off, the wide distances took the MH5 (a small arm, in AHAT frames) 15.6 deg
// round into a basin that covered 0.70 of its pixels against the right pose's 0.95, and no fit
// could then replace it: in a wrapped frame neither pose was seen through, and a re-reference
// needs strictly less (held-back draw 25's MH5 AHAT stream 0: 177 of 495 frames within 10 mm).
// A seed is one guess, not a search, so the first frame looks round it before the filter starts.
TrackResult Tracker::Impl::Acquire(Step& st) {
  const TrackerSettings& s = settings;
  Measurement best = st.m;
  for (int k = -s.search_yaw_steps; k <= s.search_yaw_steps; ++k) {
    if (k == 0) continue;
    ++st.out.hypotheses;
    const Iso3 start = *seed * MakeYawPose(0, 0, 0, k * s.search_yaw_step_deg * kDegree);
    const Measurement x = Measure(st.frame, start, WideDistances(), s.icp_iterations, &st.out);
    LogMeasurement(fmt::format("the seed turned {} deg", k * s.search_yaw_step_deg), x);
    if (x.fits && Reacquires(x) && (!Reacquires(best) || x.support > best.support)) best = x;
  }
  st.out.T_world_base_measured = best.T_world_base;
  if (!Reacquires(best)) return Finish(st, TrackState::kLost);  // best fits: the first fit did (TakeFit)
  seed.reset();
  return Restart(st, best);
}

// A pose found while lost restarts at once only when there is no filter to replace (the first
// frames after a seed); otherwise it becomes a candidate if it explains the frame clearly better.
std::optional<TrackResult> Tracker::Impl::Found(Step& st, const Measurement& x, std::string_view how, bool jump_view) {
  if (!st.tracking) {
    spdlog::info("tracker: acquired {}", how);
    seed.reset();
    return Restart(st, x);
  }
  if (!ClearlyBetter(st, x, jump_view)) return std::nullopt;
  StartCandidate(st, x, jump_view ? Bar::kClearlyBetterJumpView : Bar::kClearlyBetter, how);
  if (candidate_frames >= settings.confirm_frames) return AdoptCandidate(st, x);
  return Finish(st, TrackState::kLost);
}

// Lost. If the world moved under a steady head, the robot is where the camera last saw it;
// when the camera has not jumped, that guess is off by the head's motion, so it waits for a
// second lost frame like the grid search.
TrackResult Tracker::Impl::Reacquire(Step& st) {
  const TrackerSettings& s = settings;
  const DepthFrame& frame = st.frame;
  ++lost_frames;
  if (candidate) return Finish(st, TrackState::kLost);  // being confirmed: no search meanwhile
  if (!st.jumped && lost_frames <= s.lost_frames_before_search) return Finish(st, TrackState::kLost);
  std::vector<Iso3> guesses = {st.predicted};
  std::optional<Iso3> relative = jump_guess;
  if (!relative && last_T_world_base && last_T_world_camera)
    relative = StateToPose(PoseToState(frame.T_world_camera * last_T_world_camera->inverse() * *last_T_world_base));
  if (relative) {
    // Across a jump of the world under a steady head the camera's view is centimetres off, so
    // the tracking distances come first: the wide ones reach the clutter round a thin arm and
    // can pull the fit off a right guess.
    // (The view of a pending jump was measured, and counted, in ChallengeWithJumpView.)
    if (!st.pending_view) ++st.out.hypotheses;
    Measurement r = st.pending_view ? *st.pending_view
                                    : Measure(frame, *relative, s.icp_distances_m, s.icp_iterations, &st.out);
    bool jump_view = jump_guess.has_value();  // the relaxed coverage bar holds for this fit only
    if (jump_view && Wraps(frame))
      st.jump_view_agreement = r.start_hidden ? 1.0 : std::max(r.start_agreement, r.fits ? r.agreement : 0.0);
    if (!Reacquires(r, jump_view)) {
      ++st.out.hypotheses;
      r = Measure(frame, *relative, WideDistances(), s.icp_iterations, &st.out);
      jump_view = false;
    }
    LogMeasurement(jump_guess ? "the camera's view at the jump" : "the camera's view", r);
    if (Reacquires(r, jump_view))
      if (auto result = Found(st, r, "from the camera's view", jump_view)) return *result;
    guesses.push_back(*relative);
  }
  if (const auto pose = GridSearch(frame, guesses, &st.out)) {
    const Measurement refined = Measure(frame, *pose, s.icp_distances_m, s.icp_iterations, &st.out);
    LogMeasurement("search", refined);
    if (Reacquires(refined))
      if (auto result = Found(st, refined, fmt::format("by a search of {} poses", st.out.hypotheses))) return *result;
  }
  lost_frames = 0;  // the next search waits again
  return Finish(st, TrackState::kLost);
}

Result<TrackResult> Tracker::Process(const DepthFrame& reported, const JointValues& joints) {
  ARREF_RETURN_IF_ERROR(CheckDepthFrame(reported));
  if (!seeded()) return Status::FailedPrecondition("tracker: no first guess of the robot's pose (Seed)");
  Impl& I = *impl_;
  std::optional<DepthFrame> corrected;
  const DepthFrame& frame = I.AtExposure(reported, &corrected);
  I.MeasureDepthNoise(frame);
  Impl::Step st(frame, I.CameraJumped(frame));
  LapTimer lap;
  const Status posed = I.caster.Pose(*I.robot, I.robot->ClampedToLimits(joints));
  ARREF_RETURN_IF_ERROR(posed.WithContext("tracker: posing the robot"));
  st.out.model_ms += lap.Lap();
  const TrackerSettings& s = I.settings;
  I.ExplainByFilter(st);
  if (auto adopted = I.ConfirmCandidate(st)) return *adopted;
  I.ChallengeWithJumpView(st);
  const Measurement& m = st.m;
  // Out of view where the filter says; after a camera jump, the world may have moved it.
  if (m.model_points < s.min_model_points && !st.jumped) return I.Finish(st, TrackState::kNoRobot);
  // No fit, but the filter's pose still explains the frame (the depth near it too sparse or
  // mostly an occluder for ICP): the pose holds, and nothing is searched.
  if (!m.fits && st.tracking && !st.jumped && (m.start_support >= s.min_reacquire_agreement || st.hidden))
    return I.Finish(st, TrackState::kTracking);
  if (m.fits) return I.TakeFit(st);
  I.FusePartlySeen(st);  // fused or not, the tracker is lost and searches on
  return I.Reacquire(st);
}

}  // namespace arref
