#include "arref/icp/fast_icp.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <Eigen/Cholesky>
#include <fmt/format.h>

#include <cmath>
#include <limits>

#include "arref/base/stats.h"

namespace arref {
namespace {

using Mat6 = Eigen::Matrix<double, 6, 6>;
using Vec6 = Eigen::Matrix<double, 6, 1>;

// Normal equations of one Gauss-Newton step, summed over correspondences.
struct Normal {
  Mat6 H = Mat6::Zero();
  Vec6 b = Vec6::Zero();
  double cost = 0.0;  // the robust (Geman-McClure) cost of the pairs
  std::size_t count = 0;
  Normal& operator+=(const Normal& o) {
    H += o.H;
    b += o.b;
    cost += o.cost;
    count += o.count;
    return *this;
  }
};

// One weighted residual r with Jacobian J, into the normal equations.
void AddPair(Normal& eq, double r, const Vec6& J, double w) {
  eq.H.selfadjointView<Eigen::Upper>().rankUpdate(J, w);
  eq.b += w * r * J;
}

// Geman-McClure (Black & Rangarajan 1996): the weight (s^2 / (s^2 + r^2))^2 of a residual; its
// robust cost s^2 r^2 / (s^2 + r^2) is added to *cost.
double Weight(double r_sq, double scale_sq, double* cost) {
  const double k = scale_sq / (scale_sq + r_sq);
  *cost += k * r_sq;
  return k * k;
}

// Both metrics use the left perturbation T <- exp(xi) T, xi = (v, w), under which the
// transformed point p' = T p moves by v + w x p'. A residual a . (p' - q) along a unit axis a
// then has dr/dxi = [a^T, (p' x a)^T].
// Point-to-plane (a = the target normal n): Low 2004, "Linear least-squares optimization for
// point-to-plane ICP", eq. 8, in Lie-algebra form. Point-to-point (Besl & McKay 1992): the
// three residuals along x, y and z, one robust weight on their norm |p' - q|.
template <IcpMetric kMetric>
void AddCorrespondence(Normal& eq, const Vec3f& p, const Vec3f& q, const Vec3f& n, double scale_sq, double weight) {
  const Eigen::Vector3d pd = p.cast<double>();
  if constexpr (kMetric == IcpMetric::kPointToPlane) {
    const double r = n.dot(p - q);
    Vec6 J;
    J << n.cast<double>(), pd.cross(n.cast<double>());
    AddPair(eq, r, J, weight * Weight(r * r, scale_sq, &eq.cost));
  } else {
    // Stacked over x, y and z, J = [I, -[p']x]: J^T J and J^T e in closed form (the upper
    // triangle is what BuildNormalEquations keeps).
    const Eigen::Vector3d e = (p - q).cast<double>();
    const double w = weight * Weight(e.squaredNorm(), scale_sq, &eq.cost);
    Eigen::Matrix3d skew;
    skew << 0, -pd.z(), pd.y(), pd.z(), 0, -pd.x(), -pd.y(), pd.x(), 0;
    eq.H.topLeftCorner<3, 3>().diagonal().array() += w;
    eq.H.topRightCorner<3, 3>() -= w * skew;
    eq.H.bottomRightCorner<3, 3>() += w * (pd.squaredNorm() * Eigen::Matrix3d::Identity() - pd * pd.transpose());
    eq.b.head<3>() += w * e;
    eq.b.tail<3>() += w * pd.cross(e);
  }
  ++eq.count;
}

// A source point's own weight (AlignCoarseToFine's weights), times its robust one.
struct Source {
  const PointCloud& cloud;
  std::span<const float> weights;
  double WeightOf(std::size_t i) const { return weights.empty() ? 1.0 : weights[i]; }
};

template <IcpMetric kMetric>
Normal Accumulate(const Source& src, const TargetCloud& target, const Eigen::Isometry3f& T,
                  const IcpSettings& s, std::size_t begin, std::size_t end, MovingNearest* near) {
  const PointCloud& source = src.cloud;
  Normal eq;
  const float max_sq = static_cast<float>(s.max_correspondence_m * s.max_correspondence_m);
  const double scale_sq = s.kernel_scale_m * s.kernel_scale_m;
  const Eigen::Matrix3f R = T.linear();
  const bool check_normals = source.has_normals();
  for (std::size_t i = begin; i < end; ++i) {
    const Vec3f p = T * source.points[i];
    std::uint32_t j;
    float sq;
    if (!near[i].NearestWithin(target.index(), p, max_sq, &j, &sq)) continue;
    const Vec3f& n = target.normals()[j];
    if (check_normals && (R * source.normals[i]).dot(n) < s.min_normal_cos) continue;
    AddCorrespondence<kMetric>(eq, p, target.index().points()[j], n, scale_sq, src.WeightOf(i));
  }
  return eq;
}

Normal BuildNormalEquations(const Source& source, const TargetCloud& target, const Iso3& T,
                            const IcpSettings& s, MovingNearest* near) {
  const Eigen::Isometry3f Tf = T.cast<float>();
  Normal eq = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, source.cloud.size(), 256), Normal{},
      [&](const tbb::blocked_range<std::size_t>& r, Normal acc) {
        acc += s.metric == IcpMetric::kPointToPlane
                   ? Accumulate<IcpMetric::kPointToPlane>(source, target, Tf, s, r.begin(), r.end(), near)
                   : Accumulate<IcpMetric::kPointToPoint>(source, target, Tf, s, r.begin(), r.end(), near);
        return acc;
      },
      [](Normal a, const Normal& b) { return a += b; });
  eq.H.triangularView<Eigen::Lower>() = eq.H.transpose();
  return eq;
}

// Solves for xi; in 4-DoF mode only x, y, z and the rotation about z move.
Vec6 SolveStep(const Normal& eq, bool yaw_only) {
  Vec6 xi = Vec6::Zero();
  if (yaw_only) {
    const std::array<int, 4> dof = {0, 1, 2, 5};
    Eigen::Matrix4d H;
    Eigen::Vector4d b;
    for (int r = 0; r < 4; ++r) {
      b(r) = eq.b(dof[r]);
      for (int c = 0; c < 4; ++c) H(r, c) = eq.H(dof[r], dof[c]);
    }
    const Eigen::Vector4d x = H.ldlt().solve(-b);
    for (int r = 0; r < 4; ++r) xi(dof[r]) = x(r);
  } else {
    xi = eq.H.ldlt().solve(-eq.b);
  }
  return xi;
}

Iso3 Exp(const Vec6& xi) {
  Iso3 T = Iso3::Identity();
  const double angle = xi.tail<3>().norm();
  if (angle > 1e-12) T.linear() = Eigen::AngleAxisd(angle, xi.tail<3>() / angle).toRotationMatrix();
  T.translation() = xi.head<3>();
  return T;
}

// Each source point's search starts from what its last one found (near: one per source point),
// in this call or an earlier one at another correspondence distance.
IcpStats AlignFrom(const Source& source, const TargetCloud& target, const Iso3& T_target_source,
                   const IcpSettings& settings, std::vector<MovingNearest>& near) {
  IcpStats stats;
  stats.T_target_source = T_target_source;
  double last_cost = -1;
  for (; stats.iterations < settings.max_iterations; ++stats.iterations) {
    if (Cancelled(settings.cancel)) {  // one iteration is ~0.1-2 ms: polled before each
      stats.cancelled = true;
      break;
    }
    const Normal eq = BuildNormalEquations(source, target, stats.T_target_source, settings, near.data());
    stats.correspondences = eq.count;
    if (eq.count < 6) break;  // too few to constrain the pose: keep the last one
    // The stop watches the robust cost unweighted: a source's own weights shape the step, and
    // the test only asks whether the fit still changes.
    const double cost = eq.cost / static_cast<double>(source.cloud.size());
    if (last_cost > 0 && std::abs(last_cost - cost) < settings.converged_cost_ratio * last_cost) {
      stats.converged = true;  // the pose the cost was measured at is kept; no further step
      break;
    }
    last_cost = cost;
    const Vec6 xi = SolveStep(eq, settings.yaw_only);
    if (!xi.allFinite()) break;
    stats.T_target_source = Exp(xi) * stats.T_target_source;
    if (xi.head<3>().norm() < settings.converged_translation_m && xi.tail<3>().norm() < settings.converged_rotation_rad) {
      stats.converged = true;
      ++stats.iterations;
      break;
    }
  }
  return stats;
}

}  // namespace

TargetCloud::TargetCloud(PointCloud scene) : normals_(std::move(scene.normals)), index_(std::move(scene.points)) {}

IcpStats Align(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
               const IcpSettings& settings) {
  std::vector<MovingNearest> near(source.size());
  return AlignFrom({source, {}}, target, T_target_source, settings, near);
}

Result<IcpStats> AlignCoarseToFine(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
                                   const std::vector<double>& distances_m, IcpSettings settings,
                                   std::span<const float> weights) {
  if (!weights.empty() && weights.size() != source.size())
    return Status::InvalidArgument(fmt::format("AlignCoarseToFine: {} weights for {} source points", weights.size(),
                                               source.size()));
  IcpStats total;
  total.T_target_source = T_target_source;
  std::vector<MovingNearest> near(source.size());  // a level starts where the last one's searches ended
  for (double d : distances_m) {
    settings.max_correspondence_m = d;
    settings.kernel_scale_m = std::max(0.005, d / 3);  // the kernel tightens with the search radius
    const IcpStats level = AlignFrom({source, weights}, target, total.T_target_source, settings, near);
    total.T_target_source = level.T_target_source;
    total.iterations += level.iterations;
    total.converged = level.converged;
    total.correspondences = level.correspondences;
    if (level.cancelled) {
      total.cancelled = true;
      break;
    }
  }
  return total;
}

AlignmentScore ScoreAlignment(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
                              double inlier_threshold_m, double min_normal_cos) {
  const Eigen::Isometry3f T = T_target_source.cast<float>();
  const Eigen::Matrix3f R = T.linear();
  const float max_sq = static_cast<float>(inlier_threshold_m * inlier_threshold_m);
  struct Sum { std::size_t inliers = 0; double sq = 0; };
  const Sum sum = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, source.size(), 512), Sum{},
      [&](const tbb::blocked_range<std::size_t>& r, Sum acc) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
          std::uint32_t j;
          float sq;
          if (!target.index().NearestWithin(T * source.points[i], max_sq, &j, &sq)) continue;
          if ((R * source.normals[i]).dot(target.normals()[j]) < min_normal_cos) continue;
          ++acc.inliers;
          acc.sq += sq;
        }
        return acc;
      },
      [](Sum a, const Sum& b) { a.inliers += b.inliers; a.sq += b.sq; return a; });
  AlignmentScore score;
  if (source.size() == 0) return score;
  score.inlier_fraction = static_cast<double>(sum.inliers) / static_cast<double>(source.size());
  score.rms_inliers_m = sum.inliers ? std::sqrt(sum.sq / static_cast<double>(sum.inliers)) : 0.0;
  return score;
}

double MedianPlaneDistance(const PointCloud& source, const TargetCloud& target, const Iso3& T_target_source,
                           double max_distance_m, double min_normal_cos) {
  const Eigen::Isometry3f T = T_target_source.cast<float>();
  const float max_sq = static_cast<float>(max_distance_m * max_distance_m);
  constexpr float kNone = -1.0f;  // no normal-compatible target point within reach
  std::vector<float> distances(source.size(), kNone);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, source.size(), 512), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      std::uint32_t j;
      float sq;
      const Vec3f p = T * source.points[i];
      if (!target.index().NearestWithin(p, max_sq, &j, &sq)) continue;
      const Vec3f& n = target.normals()[j];
      if ((T.linear() * source.normals[i]).dot(n) < min_normal_cos) continue;
      distances[i] = std::abs(n.dot(p - target.index().points()[j]));
    }
  });
  std::erase(distances, kNone);
  if (distances.empty()) return std::numeric_limits<double>::infinity();
  return UpperMiddle(distances);
}

}  // namespace arref
