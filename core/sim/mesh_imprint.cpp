#include "mesh_imprint.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "arref/scene/metrics.h"

namespace arref::sim::detail {

MeshImprint::MeshImprint(PointCloud robot_world, const Vec3& base_world)
    : robot_(std::move(robot_world)), base_(base_world), moved_sum_(robot_.size(), 0.0), views_(robot_.size(), 0) {}

void MeshImprint::AddView(const PinholeCamera& camera, const Iso3& T_world_camera_true,
                          const Iso3& T_world_camera_believed, const RangeImage& range, double tolerance_m) {
  const Iso3 T_camera_world = T_world_camera_true.inverse();
  // Fused where the believed camera puts what the true one measured.
  const Iso3 T_fused_true = T_world_camera_believed * T_camera_world;
  const Vec3 eye = T_world_camera_true.translation();
  for (std::size_t i = 0; i < robot_.size(); ++i) {
    const Vec3 x = robot_.points[i].cast<double>();
    const Vec3 n = robot_.normals[i].cast<double>();
    if (n.dot(eye - x) <= 0) continue;
    const int pixel = camera.PixelOf(Vec3(T_camera_world * x));
    if (pixel < 0) continue;
    const double r = range[static_cast<std::size_t>(pixel)];
    if (!(r > 0) || std::abs(r - (x - eye).norm()) > tolerance_m) continue;
    moved_sum_[i] += n.dot(T_fused_true * x - x);
    ++views_[i];
  }
}

std::size_t MeshImprint::seen() const {
  return static_cast<std::size_t>(std::count_if(views_.begin(), views_.end(), [](int v) { return v > 0; }));
}

std::optional<Iso3> MeshImprint::Motion(const std::function<Iso3(const Vec3&)>& T_moved_true_at) const {
  // Linearised point-to-plane least squares in (x, y, z, yaw): n . (t + yaw z x (p - base)) = n . (p' - p).
  Eigen::Matrix4d JtJ = Eigen::Matrix4d::Zero();
  Eigen::Vector4d Jtr = Eigen::Vector4d::Zero();
  for (std::size_t i = 0; i < robot_.size(); ++i) {
    if (views_[i] == 0) continue;
    const Vec3 x = robot_.points[i].cast<double>();
    const Vec3 n = robot_.normals[i].cast<double>();
    Vec3 moved = x + n * (moved_sum_[i] / views_[i]);
    if (T_moved_true_at) moved = T_moved_true_at(x) * moved;
    const Vec3 arm = x - base_;
    const Eigen::Vector4d J(n.x(), n.y(), n.z(), n.dot(Vec3::UnitZ().cross(arm)));
    JtJ += J * J.transpose();
    Jtr += J * n.dot(moved - x);
  }
  if (seen() < 20) return std::nullopt;
  const Eigen::LDLT<Eigen::Matrix4d> solver(JtJ);
  if (solver.info() != Eigen::Success) return std::nullopt;
  const Eigen::Vector4d u = solver.solve(Jtr);
  return Iso3(Eigen::Translation3d(base_ + u.head<3>()) * Eigen::AngleAxisd(u[3], Vec3::UnitZ()) *
              Eigen::Translation3d(-base_));
}

double MeshImprint::AddOf(const Iso3& T_mesh_true) const {
  if (robot_.points.empty()) return -1.0;
  return ComparePoses(T_mesh_true, Iso3::Identity(), robot_.points).add_m;
}

}  // namespace arref::sim::detail
