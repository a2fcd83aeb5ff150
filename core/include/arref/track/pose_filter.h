// A Kalman filter (covariance form) on the gravity-aligned 4-DoF pose of the
// robot base in the headset's world (x, y, z, yaw). The base stands still in the world; the
// world itself creeps with head-tracking drift (a random walk) and jumps when the headset
// re-localises. Measurements that disagree beyond a chi-square gate are rejected, and a run of
// rejected measurements that agree with each other is taken as a world jump.
#pragma once

#include <Eigen/Core>
#include <deque>

#include "arref/base/geometry.h"

namespace arref {

using Vec4 = Eigen::Vector4d;
using Mat4 = Eigen::Matrix4d;

// (x, y, z, yaw) of a gravity-aligned pose; its roll and pitch are dropped.
Vec4 PoseToState(const Iso3& T);
Iso3 StateToPose(const Vec4& s);

struct PoseFilterSettings {
  // Random-walk process noise per second: how fast head-tracking drift may move the world.
  double drift_m_per_sqrt_s = 0.003;
  double drift_rad_per_sqrt_s = 0.001;
  // Mahalanobis gate on the innovation (chi-square, 4 DoF: 18.5 is p = 0.999).
  double gate_chi2 = 18.5;
  // This many rejected measurements in a row, each within the gate of the one before, are a
  // world jump: the filter restarts at the newest.
  int jump_after = 3;
  // Added to a measurement's covariance (sigma, m and rad): ICP's own estimate knows nothing of
  // the error of the camera pose the headset reports with each frame (a few mm and tenths of a
  // degree), which moves the whole frame and dominates a single measurement.
  double min_sigma_m = 0.006;
  double min_sigma_rad = 0.006;
};

enum class FilterVerdict { kInitialised, kAccepted, kRejected, kJump };
const char* FilterVerdictName(FilterVerdict v);

class PoseFilter {
 public:
  explicit PoseFilter(PoseFilterSettings settings = {}) : settings_(settings) {}
  bool initialised() const { return initialised_; }
  void Reset(const Vec4& state, const Mat4& covariance, double time_s);
  void Clear() { initialised_ = false; pending_.clear(); }
  // Predicts to time_s and fuses z (covariance R). A rejected z that is not `jump_evidence`
  // (the caller found it explains the frame no better than the state does) ends the rejected
  // run instead of joining it: consistent but unsupported measurements never make a jump.
  FilterVerdict Update(const Vec4& z, const Mat4& R, double time_s, bool jump_evidence = true);
  // The state predicted to time_s (covariance grown by the drift since the last update).
  Mat4 CovarianceAt(double time_s) const;
  const Vec4& state() const { return state_; }
  const Mat4& covariance() const { return covariance_; }
  double last_time_s() const { return time_s_; }
  int rejected_in_a_row() const { return static_cast<int>(pending_.size()); }
  // The squared Mahalanobis distance of z from the state predicted to time_s.
  double Mahalanobis2(const Vec4& z, const Mat4& R, double time_s) const;

 private:
  Mat4 Floored(const Mat4& R) const;
  PoseFilterSettings settings_;
  bool initialised_ = false;
  Vec4 state_ = Vec4::Zero();
  Mat4 covariance_ = Mat4::Identity();
  double time_s_ = 0.0;
  struct Pending { Vec4 z; Mat4 R; double time_s; };
  std::deque<Pending> pending_;  // the rejected run so far
};

}  // namespace arref
