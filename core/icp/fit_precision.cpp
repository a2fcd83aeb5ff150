#include "arref/icp/fit_precision.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <unordered_set>
#include <vector>

#include "arref/scene/sampling.h"

namespace arref {
namespace {

using Vec4d = Eigen::Vector4d;
using Vec6d = Eigen::Matrix<double, 6, 1>;

// One point-to-plane pair at the fit: the model point (world), the scene's normal there and
// d r / d(x, y, z, yaw) when the base moves by (v, w) about its own vertical axis: the point
// moves by v + w e_z x d, d = p - base origin.
struct Pair {
  Vec3 p, n;
  Vec4d J;
};

Vec4d Jacobian(const Vec3& n, const Vec3& d) { return {n.x(), n.y(), n.z(), d.x() * n.y() - d.y() * n.x()}; }

// The root mean square displacement of the model's points under a covariance of (x, y, z, yaw):
// the mean over them of trace(J_p C J_p^T), J_p = [I, e_z x d].
double PointError(std::span<const Vec3f> model_base, const Iso3& T_world_base, const Eigen::Matrix4d& C) {
  double mean_sq = 0.0;
  for (const Vec3f& pb : model_base) {
    const Vec3 d = T_world_base.linear() * pb.cast<double>();
    Eigen::Matrix<double, 3, 4> Jp;
    Jp << Eigen::Matrix3d::Identity(), Vec3(-d.y(), d.x(), 0.0);
    mean_sq += (Jp * C * Jp.transpose()).trace();
  }
  return model_base.empty() ? 0.0 : std::sqrt(mean_sq / static_cast<double>(model_base.size()));
}

// The map's part (fit_precision.h): B_k = H^-1 sum_i J_i g_ik^T / m_i over the m_i eyes facing
// point i, g_ik = d(n . dp) / d(t_k, w_k) = [n, (p - eye_k) x n]. A point that no eye faces
// was still mapped, from somewhere the eyes do not say: it takes the mean over all of them (left
// out, it would pin the pose as if it had no error at all).
Eigen::Matrix4d MapCovariance(const std::vector<Pair>& pairs, const Eigen::Matrix4d& H_inv,
                              std::span<const Vec3> eyes, const TrackingError& error) {
  // faces[k * n + i]: eye k faces point i; facing[i]: how many eyes do. Tested once per pair.
  const std::size_t n = pairs.size();
  std::vector<char> faces(eyes.size() * n);
  std::vector<int> facing(n, 0);
  for (std::size_t k = 0; k < eyes.size(); ++k)
    for (std::size_t i = 0; i < n; ++i) facing[i] += faces[k * n + i] = pairs[i].n.dot(eyes[k] - pairs[i].p) > 0;
  Vec6d S;
  const double s_t = error.position_m, s_w = error.orientation_deg * std::numbers::pi / 180.0;
  S << s_t * s_t, s_t * s_t, s_t * s_t, s_w * s_w, s_w * s_w, s_w * s_w;
  Eigen::Matrix4d C = Eigen::Matrix4d::Zero();
  for (std::size_t k = 0; k < eyes.size(); ++k) {
    const Vec3& eye = eyes[k];
    Eigen::Matrix<double, 4, 6> M = Eigen::Matrix<double, 4, 6>::Zero();
    for (std::size_t i = 0; i < n; ++i) {
      const Pair& q = pairs[i];
      if (facing[i] > 0 && !faces[k * n + i]) continue;
      Vec6d g;
      g << q.n, (q.p - eye).cross(q.n);
      M += q.J * g.transpose() / static_cast<double>(facing[i] > 0 ? facing[i] : std::ssize(eyes));
    }
    const Eigen::Matrix<double, 4, 6> B = H_inv * M;
    C += B * S.asDiagonal() * B.transpose();
  }
  return C;
}

// The kept model's misfit as a length: 0 where none was measured (MedianPlaneDistance's infinity
// when no point of the model lay near the scene, or a negative value).
double KeptMisfit(const OtherSurfaceFit& other) {
  return std::isfinite(other.kept_misfit_m) && other.kept_misfit_m > 0 ? other.kept_misfit_m : 0.0;
}

// The surface model's part (fit_precision.h): a pose at one of two fits, about their mean, and
// the kept model's misfit m as a horizontal error of m (m^2 / 2 per horizontal axis).
Eigen::Matrix4d SurfaceCovariance(const Iso3& T_world_base, const OtherSurfaceFit& other) {
  const Vec3 dt = other.T_world_base.translation() - T_world_base.translation();
  const double yaw = WrapAngle(YawOf(other.T_world_base) - YawOf(T_world_base));
  const Vec4d delta(dt.x(), dt.y(), dt.z(), yaw);
  const double q = std::clamp(other.chance, 0.0, 1.0);
  const double m = KeptMisfit(other);
  const Vec4d misfit(m * m / 2, m * m / 2, 0.0, 0.0);
  return q * (1.0 - q) * delta * delta.transpose() + Eigen::Matrix4d(misfit.asDiagonal());
}

}  // namespace

FitPrecision MeasurePrecision(std::span<const Vec3f> model_base, std::span<const Vec3f> model_normals_base,
                              const TargetCloud& scene, const Iso3& T_world_base, std::span<const Vec3> eyes_world,
                              const OtherSurfaceFit* other_surface, const PrecisionSettings& s) {
  FitPrecision out;
  const bool check_normals = model_normals_base.size() == model_base.size();
  const Eigen::Isometry3f T = T_world_base.cast<float>();
  const Vec3 origin = T_world_base.translation();
  const float max_sq = static_cast<float>(s.max_distance_m * s.max_distance_m);
  std::vector<Pair> pairs;
  Eigen::Matrix4d H = Eigen::Matrix4d::Zero();
  double sum_sq = 0.0;
  std::unordered_set<std::uint64_t> cells;
  for (std::size_t i = 0; i < model_base.size(); ++i) {
    const Vec3f p = T * model_base[i];
    std::uint32_t j;
    float sq;
    if (!scene.index().NearestWithin(p, max_sq, &j, &sq)) continue;
    const Vec3f& n = scene.normals()[j];
    if (check_normals && (T.linear() * model_normals_base[i]).dot(n) < s.min_normal_cos) continue;
    const double r = n.dot(p - scene.index().points()[j]);
    const Vec3 pd = p.cast<double>(), nd = n.cast<double>();
    pairs.push_back({pd, nd, Jacobian(nd, pd - origin)});
    H += pairs.back().J * pairs.back().J.transpose();
    sum_sq += r * r;
    if (s.correlation_m > 0) cells.insert(CellKey(model_base[i], s.correlation_m));
  }
  out.pairs = pairs.size();
  if (out.pairs < 5) return out;
  const Eigen::LDLT<Eigen::Matrix4d> ldlt(H);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().array() > 1e-12).all()) return out;
  const Eigen::Matrix4d H_inv = ldlt.solve(Eigen::Matrix4d::Identity());
  out.independent_pairs = s.correlation_m > 0 ? cells.size() : out.pairs;
  const double variance = sum_sq / static_cast<double>(out.pairs - 4);
  const double dependence = static_cast<double>(out.pairs) / static_cast<double>(std::max<std::size_t>(out.independent_pairs, 1));
  auto symmetric = [](const Eigen::Matrix4d& C) -> Eigen::Matrix4d { return 0.5 * (C + C.transpose()); };
  out.fit_covariance = symmetric(variance * dependence * H_inv);
  out.map_covariance = symmetric(MapCovariance(pairs, H_inv, eyes_world, s.view_error));
  if (other_surface) {
    out.surface_covariance = SurfaceCovariance(T_world_base, *other_surface);
    out.surface_misfit_m = KeptMisfit(*other_surface);
  }
  out.residual_rms_m = std::sqrt(sum_sq / static_cast<double>(out.pairs));
  out.expected_error_m = PointError(model_base, T_world_base, out.covariance());
  out.fit_error_m = PointError(model_base, T_world_base, out.fit_covariance);
  out.map_error_m = PointError(model_base, T_world_base, out.map_covariance);
  out.surface_error_m = PointError(model_base, T_world_base, out.surface_covariance);
  out.valid = true;
  return out;
}

}  // namespace arref
