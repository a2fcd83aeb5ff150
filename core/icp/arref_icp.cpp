// arref-icp: robust initialisation by a gravity-aligned 4-DoF search around the seed, then
// point-to-plane ICP of the robot as the headset would mesh it (model_reconstruction.h), or of
// the model points a person can see when no such surface is given.
//
// Why: the headset's world is gravity aligned and robots stand upright, so T_world_base is
// x, y, z and yaw up to small tilt. Local ICP falls into a
// wrong basin beyond ~45 degrees of yaw or ~0.3 m of position error, so every yaw is tried;
// unseen model surfaces pull ICP 2-3 cm off, and the fused mesh's shell another 4-10 mm, so
// the surface fitted is the one a headset would produce (docs/engine.md).
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <limits>
#include <memory>
#include <numbers>
#include <numeric>
#include <optional>
#include <span>

#include <tbb/parallel_for.h>

#include "arref/icp/fast_icp.h"
#include "arref/fusion/model_visibility.h"
#include "arref/icp/arref_icp.h"
#include "arref/fusion/robot_side.h"
#include "arref/scene/sampling.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/scene/supports.h"
#include "arref/fusion/tracking_error.h"
#include "arref/base/clock.h"

namespace arref {
namespace {

struct Candidate {
  Iso3 T_world_base;
  double score = 0.0;
  int iterations = 0;
  bool settled = false;  // the pose search's settling levels ran (CoarseSearch)
};

// The heights an upright base may stand at: on each horizontal support near the seed (floor,
// pedestal or table top) within reach of the seed's height error, its resting surface on it.
std::vector<double> SupportedBaseHeights(const ArrefIcpInput& in) {
  const PointCloud& model = in.model_base;
  const ArrefIcpParams& p = in.params;
  if (!p.support_search) return {};
  const Vec3 seed = in.T_world_seed.translation();
  // The robot side knows which links stand still (RestingHeight); a bare model rests on the
  // origin of its base frame, or on its lowest point when something lies below it.
  double z_min = 0.0;
  if (in.robot) {
    z_min = in.robot->resting_height();
  } else {
    for (const Vec3f& q : model.points) z_min = std::min(z_min, static_cast<double>(q.z()));
  }
  SupportSearch search;
  search.centre = seed;
  search.radius_m = 1.5 * p.seed_error_m;
  std::vector<double> heights;
  for (const Support& s : FindSupports(in.scene_world, search))
    if (std::abs(s.z - seed.z()) <= p.seed_error_m + p.support_margin_m) heights.push_back(s.z - z_min);
  spdlog::debug("arref-icp: {} supported base heights (resting on {:.3f} m of the base frame)", heights.size(), z_min);
  return heights;
}

// Where the search starts in height: the supported heights, else the seed's less the offsets.
std::vector<double> BaseHeights(const ArrefIcpInput& in, std::vector<double> heights) {
  if (heights.empty())
    for (double dz : in.params.height_offsets_m) heights.push_back(in.T_world_seed.translation().z() + dz);
  return heights;
}

// A fitted base within the mesh's resolution of a support rests on it: the support's height,
// averaged over hundreds of floor or table points, is surer than the few horizontal faces of the
// robot itself (a small arm on a coarse mesh tilts its fit by several millimetres in height).
Iso3 RestOnSupport(const ArrefIcpInput& in, const std::vector<double>& supported, Iso3 T_world_base,
                   std::vector<std::string>* stages) {
  const double tolerance = in.voxel_m > 0 ? in.voxel_m : in.params.support_margin_m / 4;
  double best = tolerance;
  std::optional<double> rest;
  for (double z : supported) {
    const double d = std::abs(z - T_world_base.translation().z());
    if (d < best) best = d, rest = z;
  }
  if (!rest) return T_world_base;
  T_world_base.translation().z() = *rest;
  stages->push_back("rests-on-support");
  return T_world_base;
}

// Correspondence distances of the refinement: from capturing a coarse pose's basin (approach,
// on ArrefIcpParams::approach_points) down to the noise of a headset mesh (polish: depth noise
// of 4-12 mm). A pose already refined once is only polished.
const std::vector<double> kApproachLevels = {0.08, 0.04};
const std::vector<double> kPolishLevels = {0.02, 0.012};

// The pose search's lengths, from the robot's size rather than from any one robot. The capture
// level must span half the gap between two yaw hypotheses at the robot's outer points: turned
// by pi / n about its base axis, a point at radius r moves 2 r sin(pi / 2n) (0.26 r for 12 yaws),
// r the 90th percentile of the fitted model's distances from that axis, so that a few outlying
// points do not set it. It spans a user's placement error too (placement_error_m). The settling
// levels go from half of it down to where the approach starts; the wide search's grid step is
// the capture's reach, so that neighbouring starts' basins meet.
struct SearchLengths {
  std::vector<double> capture_m;  // the one capture level
  std::vector<double> settle_m;
  double grid_step_m = 0.0;
};

double OuterRadius(const PointCloud& model_base) {
  std::vector<float> r;
  r.reserve(model_base.points.size());
  for (const Vec3f& q : model_base.points) r.push_back(q.head<2>().norm());
  if (r.empty()) return 0.0;
  const auto nth = r.begin() + static_cast<std::ptrdiff_t>(r.size() * 9 / 10);
  std::nth_element(r.begin(), nth, r.end());
  return *nth;
}

SearchLengths LengthsFor(const PointCloud& coarse_base, const ArrefIcpParams& p) {
  const double half_gap = std::numbers::pi / p.yaw_hypotheses;
  const double chord = 2.0 * OuterRadius(coarse_base) * std::sin(half_gap / 2.0);
  const double capture = std::max(p.placement_error_m, chord);
  SearchLengths out;
  out.capture_m = {capture};
  out.settle_m = {std::max(capture / 2, kApproachLevels.front()), kApproachLevels.front()};
  out.grid_step_m = p.position_step_m > 0 ? p.position_step_m : capture;
  spdlog::debug("arref-icp: capture {:.3f} m (yaw chord {:.3f} m), grid step {:.3f} m", capture, chord, out.grid_step_m);
  return out;
}

std::vector<Iso3> Hypotheses(const Iso3& seed, const std::vector<double>& heights, const ArrefIcpParams& p,
                             double grid_step_m, int position_steps) {
  std::vector<Iso3> out;
  const Vec3 c = seed.translation();
  const double yaw0 = YawOf(seed);
  for (int ix = -position_steps; ix <= position_steps; ++ix)
    for (int iy = -position_steps; iy <= position_steps; ++iy) {
      if (position_steps > 0 && ix == 0 && iy == 0) continue;  // the centre was searched already
      const double dx = ix * grid_step_m, dy = iy * grid_step_m;
      if (position_steps > 0 && std::hypot(dx, dy) > p.seed_error_m + 0.5 * grid_step_m) continue;
      for (double z : heights)
        for (int k = 0; k < p.yaw_hypotheses; ++k)
          out.push_back(MakeYawPose(c.x() + dx, c.y() + dy, z, yaw0 + 2 * std::numbers::pi * k / p.yaw_hypotheses));
    }
  return out;
}

// Coarse 4-DoF alignment of each hypothesis on a thin model, scored at 3 cm. Hypotheses run
// in parallel (each small ICP on one thread scales better than splitting 400 points).
// arref-icp's ICP stays in the 4-DoF subgroup (robots stand upright in a gravity-aligned world).
// Every ICP of the method polls the request's token before each iteration (fast_icp.h).
IcpSettings YawOnly(const ArrefIcpParams& p, int max_iterations, const CancelToken* cancel) {
  IcpSettings s;
  s.metric = p.metric;
  s.yaw_only = true;
  s.max_iterations = max_iterations;
  s.cancel = cancel;
  return s;
}

Status CancelledIn(const char* step) { return Status::Cancelled(fmt::format("arref-icp: cancelled in the {}", step)); }

// AlignCoarseToFine, with a cancelled alignment as the error it is for the method.
Result<IcpStats> AlignOrCancel(const PointCloud& source, const TargetCloud& target, const Iso3& start,
                               const std::vector<double>& levels, const IcpSettings& s, const char* step,
                               std::span<const float> weights = {}) {
  ARREF_ASSIGN_OR_RETURN(IcpStats st, AlignCoarseToFine(source, target, start, levels, s, weights));
  if (st.cancelled) return CancelledIn(step);
  return st;
}

// The coarse levels (SearchLengths): the first captures each hypothesis's basin, the others
// settle it; 6 iterations each.
IcpSettings CoarseSettings(const ArrefIcpParams& p, const CancelToken* cancel) { return YawOnly(p, 6, cancel); }

Candidate CoarseCandidate(const PointCloud& coarse, const TargetCloud& target, const IcpStats& st, int iterations,
                          bool settled) {
  return {st.T_target_source, ScoreAlignment(coarse, target, st.T_target_source, 0.03, 0.5).inlier_fraction,
          iterations + st.iterations, settled};
}

// The settling levels for the candidates at `which` that have not had them.
Status Settle(const PointCloud& coarse, const TargetCloud& target, std::span<const std::size_t> which,
              const std::vector<double>& levels, const IcpSettings& s, std::vector<Candidate>* candidates) {
  tbb::parallel_for(std::size_t{0}, which.size(), [&](std::size_t k) {
    Candidate& c = (*candidates)[which[k]];
    if (c.settled || Cancelled(s.cancel)) return;
    const Result<IcpStats> st = AlignCoarseToFine(coarse, target, c.T_world_base, levels, s);
    if (st.ok() && !st->cancelled) c = CoarseCandidate(coarse, target, *st, c.iterations, true);
  });
  return Cancelled(s.cancel) ? CancelledIn("pose search") : Status::Ok();
}

// Every hypothesis is aligned at the capture level and scored; only the `settle` best go on to
// the settling levels, and the rest keep their captured pose and score. Only the best distinct
// candidates are refined (refine_top), and a start that scores low once captured does not end
// among them: the settling levels were two thirds of the search's time for the 36-48 starts
// of 12 yaws on 3-4 support heights.
Result<std::vector<Candidate>> CoarseSearch(const PointCloud& coarse, const TargetCloud& target,
                                            const std::vector<Iso3>& starts, std::size_t settle,
                                            const SearchLengths& lengths, const ArrefIcpParams& p,
                                            const CancelToken* cancel) {
  const IcpSettings s = CoarseSettings(p, cancel);
  std::vector<Candidate> out(starts.size());
  // Each hypothesis polls the token (before it starts and in every iteration), so a cancel
  // ends the running ones within an iteration and skips the rest; what they leave is dropped.
  tbb::parallel_for(std::size_t{0}, starts.size(), [&](std::size_t i) {
    if (Cancelled(cancel)) return;
    const Result<IcpStats> st = AlignCoarseToFine(coarse, target, starts[i], lengths.capture_m, s);
    // No weights: only a cancel stops it.
    if (st.ok() && !st->cancelled) out[i] = CoarseCandidate(coarse, target, *st, 0, false);
  });
  if (Cancelled(cancel)) return CancelledIn("pose search");
  std::vector<std::size_t> order(starts.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return out[a].score > out[b].score; });
  order.resize(std::min(order.size(), settle));
  ARREF_RETURN_IF_ERROR(Settle(coarse, target, order, lengths.settle_m, s, &out));
  return out;
}

bool SamePose(const Iso3& a, const Iso3& b) {
  const double dyaw = std::abs(WrapAngle(YawOf(a) - YawOf(b)));
  return (a.translation() - b.translation()).norm() < 0.05 && dyaw < 10 * std::numbers::pi / 180;
}

// The best `count` candidates that are not the same pose as a better one.
std::vector<Candidate> Distinct(std::vector<Candidate> all, std::size_t count) {
  std::stable_sort(all.begin(), all.end(), [](const Candidate& a, const Candidate& b) { return a.score > b.score; });
  std::vector<Candidate> out;
  for (const auto& c : all) {
    if (out.size() == count) break;
    if (std::none_of(out.begin(), out.end(), [&](const Candidate& o) { return SamePose(o.T_world_base, c.T_world_base); }))
      out.push_back(c);
  }
  return out;
}

Result<Candidate> Approach(const PointCloud& approach, const TargetCloud& target, const Candidate& start,
                           const ArrefIcpParams& p, const CancelToken* cancel) {
  ARREF_ASSIGN_OR_RETURN(const IcpStats st, AlignOrCancel(approach, target, start.T_world_base, kApproachLevels,
                                                          YawOnly(p, 15, cancel), "approach"));
  return Candidate{st.T_target_source, start.score, start.iterations + st.iterations};
}

// A refined pose's score, the one the margin and the turned check compare: the share of the
// fitted model's points within 2 cm of the scene with normals within 60 degrees.
double RefinedScore(const PointCloud& fine, const TargetCloud& target, const Iso3& T_world_base) {
  return ScoreAlignment(fine, target, T_world_base, 0.02, 0.5).inlier_fraction;
}

Result<Candidate> Refine(const PointCloud& fine, const TargetCloud& target, const Candidate& start,
                         const ArrefIcpParams& p, const std::vector<double>& levels, const CancelToken* cancel,
                         std::span<const float> weights = {}) {
  IcpSettings s = YawOnly(p, 15, cancel);
  ARREF_ASSIGN_OR_RETURN(IcpStats st, AlignOrCancel(fine, target, start.T_world_base, levels, s, "refinement", weights));
  int iterations = start.iterations + st.iterations;
  if (p.final_six_dof) {
    s.yaw_only = false;
    ARREF_ASSIGN_OR_RETURN(st, AlignOrCancel(fine, target, st.T_target_source, {0.012}, s, "refinement", weights));
    iterations += st.iterations;
  }
  return Candidate{st.T_target_source, RefinedScore(fine, target, st.T_target_source), iterations};
}

// A refined pose polished with another surface: the pose moves, its score stays, the
// iterations add up.
Result<Candidate> Polish(const PointCloud& surface, const TargetCloud& target, const Candidate& best,
                         const ArrefIcpParams& p, const CancelToken* cancel, std::span<const float> weights = {}) {
  ARREF_ASSIGN_OR_RETURN(const Candidate c,
                         Refine(surface, target, {best.T_world_base, best.score, 0}, p, kPolishLevels, cancel, weights));
  return Candidate{c.T_world_base, best.score, best.iterations + c.iterations};
}

// The expected surface assumes the robot was mapped from all round; a user maps one side, and
// the other side's shell differs (4-6 mm of bias away from the walked side). Each
// one-sided walk's surface is laid on the scene at the fitted pose; if one lies closer than the
// all-round surface, the fit is refined with it. The walked side is judged by the whole shell's
// shape (analysis by synthesis), not by which model parts have scene points nearby: at a
// walker's height nearly every side is seen at some angle.
Result<Candidate> RefineForWalk(const ArrefIcpInput& in, const PointCloud& all_round, const TargetCloud& target,
                                const Candidate& best, std::shared_ptr<const PointCloud>* fitted, int* walk_out,
                                std::vector<std::string>* stages) {
  const ArrefIcpParams& p = in.params;
  std::vector<std::shared_ptr<const PointCloud>> surfaces;  // the walks' surfaces, thinned as the all-round one
  for (int walk = 0; walk < RobotSide::kWalks; ++walk) {
    auto surface = in.robot->Expected(in.voxel_m, walk, p.fine_points, in.cancel);  // built once, then cached
    if (!surface.ok()) return surface.status().WithContext("arref-icp");
    surfaces.push_back(*surface);
  }
  if (Cancelled(in.cancel)) return CancelledIn("walk choice");
  std::vector<double> d(surfaces.size());
  tbb::parallel_for(std::size_t{0}, surfaces.size(), [&](std::size_t w) {
    d[w] = MedianPlaneDistance(*surfaces[w], target, best.T_world_base, 0.03, 0.5);
  });
  double best_d = MedianPlaneDistance(all_round, target, best.T_world_base, 0.03, 0.5);
  int best_walk = -1;
  for (int walk = 0; walk < RobotSide::kWalks; ++walk) {
    spdlog::debug("arref-icp: walk {}: median plane distance {:.2f} mm", walk, d[walk] * 1e3);
    if (d[walk] < best_d) best_d = d[walk], best_walk = walk;
  }
  *walk_out = best_walk;
  if (best_walk < 0) return best;
  *fitted = surfaces[best_walk];
  stages->push_back(fmt::format("walk-{}", best_walk));
  return Polish(**fitted, target, best, p, in.cancel);
}

// The scene round the fitted surface, sampled at ArrefIcpParams::context_target_density per
// voxel face: the triangles within the last polish's reach (2 cm) and a voxel of it.
std::optional<TargetCloud> DenseTargetNear(const ArrefIcpInput& in, const PointCloud& surface_base, const Iso3& T_world_base) {
  const double density = in.params.context_target_density;
  if (!(density > 0) || in.voxel_m <= 0 || !in.scene_mesh_world) return std::nullopt;
  PointCloud surface_world = surface_base;
  surface_world.Transform(T_world_base);
  const PointIndex near_surface(std::move(surface_world.points));
  const TriangleMesh near = TrianglesNear(*in.scene_mesh_world, near_surface, kPolishLevels.front() + in.voxel_m);
  const double count = std::min(density * near.SurfaceArea() / (in.voxel_m * in.voxel_m), 1e6);
  if (count < 1) return std::nullopt;
  return TargetCloud(SampleSurface(near, static_cast<std::size_t>(count), in.sample_seed));
}

// Which head positions the refit takes as eyes: those a headset maps the robot from (HoloLens
// depth reaches ~4 m), and enough of them to be a path.
constexpr double kNearestEyeM = 0.5, kFarthestEyeM = 4.0;
constexpr std::size_t kFewestPathEyes = 3, kRefitEyes = 24;

// The refit's eyes when the app sent where its wearer walked: the path in the base frame, the
// positions kNearestEyeM-kFarthestEyeM from its base, at most kRefitEyes of them spread evenly
// in time. Empty (the walk's eyes) with fewer than kFewestPathEyes.
std::vector<Vec3> EyesOfPath(std::span<const Vec3> path_world, const Iso3& T_world_base) {
  const Iso3 T_base_world = T_world_base.inverse();
  std::vector<Vec3> usable;
  for (const Vec3& p : path_world) {
    const Vec3 eye = T_base_world * p;
    if (eye.head<2>().norm() >= kNearestEyeM && eye.norm() <= kFarthestEyeM) usable.push_back(eye);
  }
  if (usable.size() < kFewestPathEyes) return {};
  const std::size_t n = usable.size(), kept = std::min(n, kRefitEyes);
  std::vector<Vec3> eyes;
  for (std::size_t i = 0; i < kept; ++i) eyes.push_back(usable[kept == n ? i : i * (n - 1) / (kept - 1)]);
  return eyes;
}

// Where the headset saw the robot from (base frame): the app's head path when it holds enough
// eyes (EyesOfPath's), else the eyes of the walk whose surface was fitted.
std::vector<Vec3> SeenFrom(std::vector<Vec3> path_eyes, int walk) {
  return path_eyes.empty() ? RobotSide::RefitEyes(walk) : path_eyes;
}

// Objects near the robot (a table 0.2 m from its base) hide parts of it from the walker and
// fuse with its shell; fitted without them, the robot is pulled towards them (about 4 mm
// towards a table, even without noise). The chosen walk's surface is fused again with the mapped objects
// round the fitted pose, and the pose polished with it.
Result<Candidate> RefineInContext(const ArrefIcpInput& in, int walk, const TargetCloud& target, const Candidate& best,
                                  std::shared_ptr<const PointCloud>* fitted, std::optional<TargetCloud>* dense,
                                  std::vector<std::string>* stages) {
  const std::vector<Vec3> eyes = EyesOfPath(in.head_path_world, best.T_world_base);
  if (!eyes.empty()) {
    stages->push_back("head-path");
  } else if (!in.head_path_world.empty()) {
    spdlog::warn("arref-icp: the head path has fewer than {} positions {}-{} m from the robot; assuming walk {}",
                 kFewestPathEyes, kNearestEyeM, kFarthestEyeM, walk);
    stages->push_back("head-path-unused");
  }
  auto surface =
      in.robot->ExpectedInContext(in.voxel_m, walk, *in.scene_mesh_world, best.T_world_base, eyes, in.cancel);
  if (surface.status().code() == StatusCode::kCancelled) return surface.status().WithContext("arref-icp");
  if (!surface.ok()) {  // the fit without the objects stands
    spdlog::warn("arref-icp: no expected surface in context, keeping the fit without it: {}", surface.status().ToString());
    stages->push_back("in-context-skipped");
    return best;
  }
  *fitted = std::make_shared<const PointCloud>(Thinned(*surface, in.params.context_points));
  stages->push_back("in-context");
  *dense = DenseTargetNear(in, **fitted, best.T_world_base);
  if (Cancelled(in.cancel)) return CancelledIn("refit in context");
  // The surface's points weighed by how far the headset's tracking error moves them, as seen
  // from the eyes it was fused from (tracking_error.h).
  const std::vector<float> weights =
      TrackingErrorWeights(**fitted, SeenFrom(eyes, walk), in.params.tracking_error);
  return Polish(**fitted, *dense ? **dense : target, best, in.params, in.cancel, weights);
}

// Which surface explains the scene: a fused headset mesh is matched by the expected surface,
// exact geometry (a CAD scene, a fine scan) by the exact one. The winner is refined with the exact
// visible surface too, and whichever lies closer to the scene's tangent planes is kept; *other gets
// the pose the other one gave (how far the choice of model moves the fit: the expected error's
// surface part, fit_precision.h), its chance and the kept one's median plane distance. Each
// model's chance is taken inversely proportional to its median plane distance: even where both
// explain the mesh alike (a mesh of another mesher, which neither model is known to match), the
// other's small where the kept one explains it far better (exact geometry: there the shell's fit
// lay 23-24 mm from an exact fit under 0.1 mm off, and even chances said 12-13 mm of expected
// error; docs/robustness.md).
// Both are polished and compared on the scene sampled densely round the robot (dense: the refit
// in context's, else sampled here), as the context's polish is: on the request's sparse samples
// the exact polish stopped 2-12 mm apart from seed to seed on one noise-free decimated mesh (docs/robustness.md, "The exact polish on the dense scene").
Result<Candidate> ExactIfCloser(const ArrefIcpInput& in, const PointCloud& expected_fine, const TargetCloud& target,
                                std::optional<TargetCloud> dense, const Candidate& best, std::vector<std::string>* stages,
                                OtherSurfaceFit* other) {
  const ArrefIcpParams& p = in.params;
  // Kept by the robot when there is one: no copy per request.
  const auto exact_kept = in.robot ? in.robot->Visible(p.fine_points)
                                   : std::make_shared<const PointCloud>(Thinned(VisiblePoints(in.model_base), p.fine_points));
  const PointCloud& exact_fine = *exact_kept;
  if (!dense) dense = DenseTargetNear(in, exact_fine, best.T_world_base);
  const TargetCloud& near = dense ? *dense : target;
  ARREF_ASSIGN_OR_RETURN(const Candidate exact, Polish(exact_fine, near, best, p, in.cancel));
  const double d_expected = MedianPlaneDistance(expected_fine, near, best.T_world_base, 0.03, 0.5);
  const double d_exact = MedianPlaneDistance(exact_fine, near, exact.T_world_base, 0.03, 0.5);
  spdlog::debug("arref-icp: median plane distance {:.1f} mm expected surface, {:.1f} mm exact", d_expected * 1e3,
                d_exact * 1e3);
  const bool exact_closer = d_exact < d_expected;
  const double kept = exact_closer ? d_exact : d_expected, rival = exact_closer ? d_expected : d_exact;
  other->chance = kept + rival > 0 ? kept / (kept + rival) : 0.5;
  other->kept_misfit_m = kept;
  if (exact_closer) {
    stages->push_back("fitted-exact-surface");
    other->T_world_base = best.T_world_base;
    return exact;
  }
  stages->push_back("fitted-expected-surface");
  other->T_world_base = exact.T_world_base;
  return best;
}

// The model points fitted, thinned for the pose search, the approach and the polish: the robot
// as the headset would mesh it when known, else its exact surface, visible parts only. Cached by
// the robot when it has them.
Result<std::array<std::shared_ptr<const PointCloud>, 3>> FittedModel(const ArrefIcpInput& in) {
  const ArrefIcpParams& p = in.params;
  const std::array<std::size_t, 3> counts = {p.coarse_points, p.approach_points, p.fine_points};
  std::array<std::shared_ptr<const PointCloud>, 3> out;
  if (in.robot && in.model_expected) {  // the all-round surface, thinned once and kept by the robot
    for (std::size_t i = 0; i < counts.size(); ++i) {
      auto kept = in.robot->Expected(in.voxel_m, -1, counts[i], in.cancel);
      if (!kept.ok()) return kept.status().WithContext("arref-icp");
      out[i] = *kept;
    }
    return out;
  }
  std::optional<PointCloud> own_visible;  // only without a given surface: no copy of one
  if (!in.model_expected) own_visible = VisiblePoints(in.model_base);
  const PointCloud& visible = in.model_expected ? *in.model_expected : *own_visible;
  for (std::size_t i = 0; i < counts.size(); ++i) out[i] = std::make_shared<const PointCloud>(Thinned(visible, counts[i]));
  return out;
}

// The refined poses of the best distinct candidates (refine_top), best first: the best and its
// rival for the margin, when they do not end at one pose.
Result<std::vector<Candidate>> RefineBest(const std::vector<Candidate>& candidates, const PointCloud& approach,
                                          const PointCloud& fine, const TargetCloud& target, const ArrefIcpParams& p,
                                          const CancelToken* cancel) {
  std::vector<Candidate> refined;
  for (const auto& c : Distinct(candidates, static_cast<std::size_t>(p.refine_top))) {
    ARREF_ASSIGN_OR_RETURN(const Candidate approached, Approach(approach, target, c, p, cancel));
    ARREF_ASSIGN_OR_RETURN(Candidate polished, Refine(fine, target, approached, p, kPolishLevels, cancel));
    spdlog::debug("arref-icp: refined from yaw {:.1f} deg (score {:.3f}) to yaw {:.1f} deg at ({:.3f}, {:.3f}), score {:.3f}",
                  YawOf(c.T_world_base) * 180 / std::numbers::pi, c.score, YawOf(polished.T_world_base) * 180 / std::numbers::pi,
                  polished.T_world_base.translation().x(), polished.T_world_base.translation().y(), polished.score);
    refined.push_back(std::move(polished));
  }
  return Distinct(refined, 2);
}

// Every yaw at the place the search found best, where no settled candidate has it yet. The
// status's margin compares the best pose with its best distinct rival (AssignStatus,
// pipeline.cpp), and a rival that never reached the robot says nothing about it: from a seed far
// from the base only one of the seed's yaws may reach the robot, at the wrong yaw of an arm that
// is nearly a figure of revolution, and its lead over rivals scoring nothing passed for
// certainty (docs/robustness.md, "Every yaw at the place found").
Result<std::vector<Candidate>> YawsAtBest(const PointCloud& coarse, const TargetCloud& target,
                                          const std::vector<Candidate>& candidates, const SearchLengths& lengths,
                                          const ArrefIcpParams& p, const CancelToken* cancel) {
  const Iso3 best = Distinct(candidates, 1).front().T_world_base;  // a copy: Distinct returns a temporary
  // The yaw search's hypotheses round the best pose, on its height, without the best's own yaw.
  const std::vector<Iso3> yaws = Hypotheses(best, {best.translation().z()}, p, 0.0, 0);
  std::vector<Iso3> starts;
  std::copy_if(yaws.begin() + 1, yaws.end(), std::back_inserter(starts), [&](const Iso3& start) {
    return std::none_of(candidates.begin(), candidates.end(),
                        [&](const Candidate& c) { return c.settled && SamePose(c.T_world_base, start); });
  });
  if (starts.empty()) return std::vector<Candidate>{};
  return CoarseSearch(coarse, target, starts, starts.size(), lengths, p, cancel);
}

// Every yaw round the seed on every base height, refined; when the seed's neighbourhood does not
// explain the robot (a weak coarse fit, or a refined one that holds too few of its points), a grid
// of positions over the seed's error too. Returns the refined poses, best first.
Result<std::vector<Candidate>> SearchPoses(const ArrefIcpInput& in,
                                           const std::array<std::shared_ptr<const PointCloud>, 3>& model,
                                           const std::vector<double>& supported, RegistrationOutput* out,
                                           LapTimer* laps) {
  const ArrefIcpParams& p = in.params;
  const PointCloud& coarse = *model[0];
  const TargetCloud& target = in.scene_target;
  const std::vector<double> heights = BaseHeights(in, supported);
  const SearchLengths lengths = LengthsFor(coarse, p);
  out->stages.push_back("yaw-search");
  ARREF_ASSIGN_OR_RETURN(std::vector<Candidate> candidates,
                         CoarseSearch(coarse, target, Hypotheses(in.T_world_seed, heights, p, lengths.grid_step_m, 0),
                                      static_cast<std::size_t>(p.settle_top), lengths, p, in.cancel));
  ARREF_ASSIGN_OR_RETURN(const auto rivals, YawsAtBest(coarse, target, candidates, lengths, p, in.cancel));
  candidates.insert(candidates.end(), rivals.begin(), rivals.end());
  const double best_coarse = Distinct(candidates, 1).front().score;
  std::vector<Candidate> refined;
  if (best_coarse >= p.expand_below_score || p.position_steps == 0) {
    out->step_ms.emplace_back("pose-search", laps->Lap());
    ARREF_ASSIGN_OR_RETURN(refined, RefineBest(candidates, *model[1], *model[2], target, p, in.cancel));
    if (refined.front().score >= p.widen_below_refined_score || p.position_steps == 0) {
      out->hypotheses = static_cast<int>(candidates.size());
      for (const auto& c : candidates) out->iterations += c.iterations;
      return refined;
    }
  }
  spdlog::debug("arref-icp: best coarse score {:.2f}, refined {:.2f}: searching positions too", best_coarse,
                refined.empty() ? 0.0 : refined.front().score);
  // The wide search settles every start, the yaw search's too: pruned to the best few before
  // its true start has settled, it lost the robot (docs/robustness.md, "settling only the best").
  std::vector<std::size_t> all(candidates.size());
  std::iota(all.begin(), all.end(), std::size_t{0});
  ARREF_RETURN_IF_ERROR(Settle(coarse, target, all, lengths.settle_m, CoarseSettings(p, in.cancel), &candidates));
  const std::vector<Iso3> wide = Hypotheses(in.T_world_seed, heights, p, lengths.grid_step_m, p.position_steps);
  ARREF_ASSIGN_OR_RETURN(const auto more, CoarseSearch(coarse, target, wide, wide.size(), lengths, p, in.cancel));
  candidates.insert(candidates.end(), more.begin(), more.end());
  ARREF_ASSIGN_OR_RETURN(const auto wide_rivals, YawsAtBest(coarse, target, candidates, lengths, p, in.cancel));
  candidates.insert(candidates.end(), wide_rivals.begin(), wide_rivals.end());
  out->stages.push_back("position-search");
  out->step_ms.emplace_back("pose-search", laps->Lap());
  out->hypotheses = static_cast<int>(candidates.size());
  for (const auto& c : candidates) out->iterations += c.iterations;
  return RefineBest(candidates, *model[1], *model[2], target, p, in.cancel);
}

// The fit turned about the base's axis far enough to be a wrong pose: 100 mm of ADD, the turn
// times the fitted model's mean distance from the axis (at most 60 degrees), either way. An arm
// that is nearly a figure of revolution keeps its score turned so, and its fit can slide along
// that flat yaw valley while every refined candidate ends at one pose, which leaves the margin
// nothing to compare (docs/robustness.md, "The fit turned about its base").
void ScoreTurned(const PointCloud& fine, const TargetCloud& target, RegistrationOutput* out) {
  constexpr double kWrongAddM = 0.1;
  double mean_r = 0;
  for (const Vec3f& q : fine.points) mean_r += q.head<2>().norm();
  mean_r /= static_cast<double>(std::max<std::size_t>(1, fine.size()));
  if (!(mean_r > 0)) return;
  const double turn = std::min(kWrongAddM / mean_r, std::numbers::pi / 3);
  double rival = 0;
  for (double sign : {-1.0, 1.0}) {
    const Iso3 turned = out->T_world_base * MakeYawPose(0, 0, 0, sign * turn);
    rival = std::max(rival, RefinedScore(fine, target, turned));
  }
  out->turned = TurnedFit{.turn_deg = turn / kDegree, .lead = RefinedScore(fine, target, out->T_world_base) - rival};
  spdlog::debug("arref-icp: turned {:.1f} deg about the base, the fit leads by {:.3f}", out->turned->turn_deg,
                out->turned->lead);
}

}  // namespace

Result<RegistrationOutput> RegisterArrefIcp(const ArrefIcpInput& in) {
  const ArrefIcpParams& p = in.params;
  if (!in.model_base.has_normals() || !in.scene_world.has_normals() ||
      (in.model_expected && !in.model_expected->has_normals()))
    return Status::FailedPrecondition("arref-icp needs normals on model and scene points");
  if (p.yaw_hypotheses < 1 || p.height_offsets_m.empty() || p.refine_top < 1 || p.settle_top < 1 || p.position_steps < 0)
    return Status::InvalidArgument("arref-icp: yaw hypotheses, heights, settle_top and refine_top must be >= 1");
  if (!(p.placement_error_m > 0) || !(p.position_step_m >= 0) || !std::isfinite(p.placement_error_m + p.position_step_m))
    return Status::InvalidArgument("arref-icp: placement_error_m must be > 0 m and position_step_m >= 0 m");
  if (Cancelled(in.cancel)) return CancelledIn("model preparation");
  ARREF_ASSIGN_OR_RETURN(const auto model, FittedModel(in));
  const PointCloud& fine = *model[2];
  const TargetCloud& target = in.scene_target;

  RegistrationOutput out;
  LapTimer laps;  // each step's time goes to out.step_ms
  const std::vector<double> supported = SupportedBaseHeights(in);
  ARREF_ASSIGN_OR_RETURN(std::vector<Candidate> refined, SearchPoses(in, model, supported, &out, &laps));
  out.stages.push_back("arref-icp");
  out.step_ms.emplace_back("refine", laps.Lap());
  int walk = -1;  // all round, unless a one-sided walk is chosen
  if (in.model_expected) {
    std::shared_ptr<const PointCloud> fitted = model[2];  // the surface polished last, shared not copied
    std::optional<TargetCloud> dense;  // the scene sampled densely round the robot, once
    if (in.robot && p.select_walk) {
      ARREF_ASSIGN_OR_RETURN(refined.front(), RefineForWalk(in, fine, target, refined.front(), &fitted, &walk, &out.stages));
      out.step_ms.emplace_back("walk-choice", laps.Lap());
    }
    if (in.robot && in.scene_mesh_world && p.in_context) {
      ARREF_ASSIGN_OR_RETURN(refined.front(),
                             RefineInContext(in, walk, target, refined.front(), &fitted, &dense, &out.stages));
      out.step_ms.emplace_back("context", laps.Lap());
    }
    ARREF_ASSIGN_OR_RETURN(refined.front(),
                           ExactIfCloser(in, *fitted, target, std::move(dense), refined.front(), &out.stages,
                                         &out.other_surface));
    out.has_other_surface = true;
    out.step_ms.emplace_back("surface-choice", laps.Lap());
  }
  out.T_world_base = p.rest_on_support ? RestOnSupport(in, supported, refined.front().T_world_base, &out.stages)
                                       : refined.front().T_world_base;
  // Set on the support, the other surface's fit moves with it: their difference is the models'.
  if (out.has_other_surface)
    out.other_surface.T_world_base.translation().z() += out.T_world_base.translation().z() - refined.front().T_world_base.translation().z();
  if (in.robot) {
    out.eyes_world = SeenFrom(EyesOfPath(in.head_path_world, out.T_world_base), walk);
    for (Vec3& eye : out.eyes_world) eye = out.T_world_base * eye;
  }
  out.score = refined.front().score;
  out.margin = refined.size() > 1 ? refined[0].score - refined[1].score : refined[0].score;
  ScoreTurned(fine, target, &out);
  out.iterations += refined.front().iterations;
  out.converged = true;
  return out;
}

}  // namespace arref
