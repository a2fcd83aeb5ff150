// Super4PCS main loop (Mellado et al. 2014, Alg. 1): repeat { draw a base from P, extract the
// pairs of Q at its two lengths (Sec. 4), extract the congruent sets (Sec. 5), score each
// candidate rigid motion by its largest common pointset (LCP, 4PCS Sec. 4) } and keep the best.
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <numeric>

#include "../global_registration.h"
#include "arref/scene/nearest_neighbor.h"
#include "super4pcs.h"

namespace arref {
namespace {

using super4pcs::Base;
using super4pcs::Congruent;

Status CheckParams(const Super4pcsParams& p) {
  if (!(p.overlap > 0 && p.overlap <= 1)) return Status::InvalidArgument("super4pcs: overlap must be in (0, 1]");
  if (!(p.delta_m >= 0)) return Status::InvalidArgument("super4pcs: delta must be >= 0 m (0: derive from the model)");
  if (p.sample_count < 4 || p.max_bases <= 0 || !(p.max_time_s > 0))
    return Status::InvalidArgument("super4pcs: sample count must be >= 4, max bases and max time > 0");
  if (!(p.terminate_lcp > 0 && p.terminate_lcp <= 1)) return Status::InvalidArgument("super4pcs: terminate LCP must be in (0, 1]");
  return Status::Ok();
}

std::vector<Vec3f> RandomSample(const std::vector<Vec3f>& points, std::size_t n, std::mt19937_64& rng) {
  if (points.size() <= n) return points;
  std::vector<std::uint32_t> order(points.size());
  std::iota(order.begin(), order.end(), 0u);
  std::shuffle(order.begin(), order.end(), rng);
  std::vector<Vec3f> out;
  out.reserve(n);
  for (std::size_t i = 0; i < n; ++i) out.push_back(points[order[i]]);
  return out;
}

double Diagonal(const std::vector<Vec3f>& points) {
  const Aabb box = BoundsOf(points);
  return box.valid() ? static_cast<double>((box.max - box.min).norm()) : 0.0;
}

// LCP (4PCS Sec. 4): the share of P's sample that lands within delta of Q under T_Q_P. Gives
// up as soon as it cannot beat `to_beat` points, which is what makes verifying thousands of
// candidates affordable.
std::size_t CountLcp(const std::vector<Vec3f>& P, const Eigen::Isometry3f& T_Q_P, const PointIndex& Q_index,
                     float delta2, std::size_t to_beat) {
  std::size_t hits = 0, misses = 0;
  const std::size_t allowed_misses = P.size() - std::min(P.size(), to_beat);
  for (const auto& p : P) {
    std::uint32_t index;
    float d2;
    Q_index.Nearest(T_Q_P * p, &index, &d2);
    if (d2 <= delta2) ++hits;
    else if (++misses > allowed_misses) return 0;
  }
  return hits;
}

double TiltDeg(const Eigen::Matrix3d& R) {
  return std::acos(std::clamp(R(2, 2), -1.0, 1.0)) * 180.0 / std::numbers::pi;
}

struct Search {
  const Super4pcsParams& params;
  double delta;
  std::vector<Vec3f> P, Q;
  const PointIndex& model_index;
  Eigen::Isometry3f best_T_Q_P = Eigen::Isometry3f::Identity();
  std::size_t best_lcp = 0;
  std::size_t candidates = 0;

  // Verifies one congruent set: a rigid fit of the base onto it, the gravity check, the LCP.
  void Verify(const Base& base, const Congruent& set) {
    Eigen::Matrix<float, 3, 4> from, to;
    for (int k = 0; k < 4; ++k) from.col(k) = base.points[k], to.col(k) = Q[set[k]];
    Eigen::Isometry3f T_Q_P(Eigen::umeyama(from, to, false));
    if ((T_Q_P * from - to).colwise().norm().maxCoeff() > 2 * delta) return;  // not rigidly congruent
    // T_Q_P maps world into the base frame; the robot's up is the world's up, up to the tilt.
    if (TiltDeg(T_Q_P.linear().cast<double>()) > params.max_tilt_deg) return;
    ++candidates;
    const std::size_t lcp = CountLcp(P, T_Q_P, model_index, static_cast<float>(delta * delta), best_lcp + 1);
    if (lcp > best_lcp) best_lcp = lcp, best_T_Q_P = T_Q_P;
  }
};

}  // namespace

// P = the (segmented) scene, Q = the model: bases drawn from the scene lie on the robot's
// seen side, which the complete model always contains. The result maps the scene onto the
// model (T_base_world); its inverse is the answer.
Result<GlobalAlignment> AlignSuper4pcs(const PointCloud& model_base, const PointCloud& scene_world,
                                       const Super4pcsParams& params) {
  ARREF_RETURN_IF_ERROR(CheckParams(params));
  if (model_base.size() < 4 || scene_world.size() < 4)
    return Status::FailedPrecondition(fmt::format("super4pcs needs at least 4 model and 4 scene points (have {} and {})",
                                                  model_base.size(), scene_world.size()));
  const double model_diagonal = Diagonal(model_base.points);
  const double delta = params.delta_m > 0 ? params.delta_m : std::clamp(0.015 * model_diagonal, 0.01, 0.03);
  std::mt19937_64 rng(params.rng_seed);
  const PointIndex model_index(model_base.points);
  Search search{params, delta, RandomSample(scene_world.points, params.sample_count, rng),
                RandomSample(model_base.points, params.sample_count, rng), model_index};
  // The base must fit in the overlap (4PCS Sec. 4): width ~ overlap x the scene's extent,
  // capped by the model's, since the robot is all that the two share.
  const double width = std::min(params.overlap * Diagonal(search.P), 0.8 * model_diagonal);
  const super4pcs::PairExtractor extractor(search.Q);

  const auto t0 = std::chrono::steady_clock::now();
  const auto target = static_cast<std::size_t>(params.terminate_lcp * static_cast<double>(search.P.size()));
  int bases = 0;
  for (; bases < params.max_bases && search.best_lcp < target; ++bases) {
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() > params.max_time_s) break;
    Base base;
    if (!super4pcs::SelectBase(search.P, width, delta, rng, &base)) continue;
    const auto pairs1 = extractor.Extract(base.d1, delta);
    const auto pairs2 = extractor.Extract(base.d2, delta);
    // The angle may be off by what delta allows at the ends of the shorter segment.
    const double angle_tolerance = 2.0 * std::asin(std::min(1.0, delta / std::min(base.d1, base.d2)));
    for (const auto& set : super4pcs::FindCongruentSets(search.Q, base, pairs1, pairs2, delta, angle_tolerance, 20000))
      search.Verify(base, set);
  }
  if (search.best_lcp == 0)
    return Status::FailedPrecondition(fmt::format(
        "no congruent set with a common pointset in {} bases (delta {:.3f} m, overlap {:.2f}, {} samples); "
        "try a larger delta or overlap",
        bases, delta, params.overlap, params.sample_count));
  GlobalAlignment out;
  out.T_world_base = search.best_T_Q_P.cast<double>().inverse();
  out.score = static_cast<double>(search.best_lcp) / static_cast<double>(search.P.size());
  out.iterations = bases;
  spdlog::debug("super4pcs: LCP {:.3f} after {} bases, {} candidates, delta {:.3f} m, width {:.2f} m", out.score, bases,
                search.candidates, delta, width);
  return out;
}

}  // namespace arref
