#include "arref/track/pose_filter.h"

#include <Eigen/Cholesky>

#include <cmath>

namespace arref {

Vec4 PoseToState(const Iso3& T) {
  const Vec3 t = T.translation();
  return {t.x(), t.y(), t.z(), YawOf(T)};
}

Iso3 StateToPose(const Vec4& s) { return MakeYawPose(s(0), s(1), s(2), s(3)); }

const char* FilterVerdictName(FilterVerdict v) {
  switch (v) {
    case FilterVerdict::kInitialised: return "initialised";
    case FilterVerdict::kAccepted: return "accepted";
    case FilterVerdict::kRejected: return "rejected";
    case FilterVerdict::kJump: return "jump";
  }
  return "?";
}

namespace {
Vec4 Innovation(const Vec4& z, const Vec4& x) {
  Vec4 y = z - x;
  y(3) = WrapAngle(y(3));
  return y;
}
}  // namespace

void PoseFilter::Reset(const Vec4& state, const Mat4& covariance, double time_s) {
  state_ = state;
  state_(3) = WrapAngle(state_(3));
  covariance_ = Floored(covariance);
  time_s_ = time_s;
  initialised_ = true;
  pending_.clear();
}

Mat4 PoseFilter::Floored(const Mat4& R) const {
  Mat4 out = R;
  const double m2 = settings_.min_sigma_m * settings_.min_sigma_m, r2 = settings_.min_sigma_rad * settings_.min_sigma_rad;
  for (int i = 0; i < 3; ++i) out(i, i) += m2;
  out(3, 3) += r2;
  return out;
}

Mat4 PoseFilter::CovarianceAt(double time_s) const {
  const double dt = std::max(0.0, time_s - time_s_);
  Mat4 P = covariance_;
  const double qm = settings_.drift_m_per_sqrt_s, qr = settings_.drift_rad_per_sqrt_s;
  for (int i = 0; i < 3; ++i) P(i, i) += qm * qm * dt;
  P(3, 3) += qr * qr * dt;
  return P;
}

double PoseFilter::Mahalanobis2(const Vec4& z, const Mat4& R, double time_s) const {
  const Mat4 S = CovarianceAt(time_s) + Floored(R);
  const Vec4 y = Innovation(z, state_);
  return y.dot(S.ldlt().solve(y));
}

FilterVerdict PoseFilter::Update(const Vec4& z, const Mat4& R, double time_s, bool jump_evidence) {
  if (!initialised_) {
    Reset(z, R, time_s);
    return FilterVerdict::kInitialised;
  }
  const Mat4 Rf = Floored(R);
  if (Mahalanobis2(z, R, time_s) > settings_.gate_chi2) {
    if (!jump_evidence) {
      pending_.clear();
      return FilterVerdict::kRejected;
    }
    // A new world agrees with itself: each rejected measurement within the gate of the last.
    if (!pending_.empty()) {
      const Pending& last = pending_.back();
      const Mat4 S = last.R + Rf;
      const Vec4 y = Innovation(z, last.z);
      if (y.dot(S.ldlt().solve(y)) > settings_.gate_chi2) pending_.clear();
    }
    pending_.push_back({z, Rf, time_s});
    if (static_cast<int>(pending_.size()) >= settings_.jump_after) {
      Reset(z, R, time_s);
      return FilterVerdict::kJump;
    }
    return FilterVerdict::kRejected;
  }
  pending_.clear();
  const Mat4 P = CovarianceAt(time_s);
  const Mat4 S = P + Rf;
  const Mat4 K = S.ldlt().solve(P).transpose();  // P S^-1 (P and S symmetric)
  state_ += K * Innovation(z, state_);
  state_(3) = WrapAngle(state_(3));
  covariance_ = (Mat4::Identity() - K) * P;
  covariance_ = 0.5 * (covariance_ + covariance_.transpose());
  time_s_ = time_s;
  return FilterVerdict::kAccepted;
}

}  // namespace arref
