// Plain geometry containers shared by every part of arref. Points are float (memory),
// transforms double (accuracy). Transform names follow T_a_b: maps frame-b coordinates into a.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <cstdint>
#include <vector>

namespace arref {

using Vec3f = Eigen::Vector3f;
using Vec3 = Eigen::Vector3d;
using Iso3 = Eigen::Isometry3d;
using Quat = Eigen::Quaterniond;
using Triangle = std::array<std::uint32_t, 3>;

// Counter-clockwise winding seen from outside (right-handed frame) gives the outward normal.
struct TriangleMesh {
  std::vector<Vec3f> vertices;
  std::vector<Triangle> triangles;

  bool empty() const { return triangles.empty(); }
  void Append(const TriangleMesh& other, const Iso3& T_this_other = Iso3::Identity());
  void Transform(const Iso3& T_new_old);
  double SurfaceArea() const;
};

// Points with optional per-point normals and weights (each empty, or the size of points).
struct PointCloud {
  std::vector<Vec3f> points;
  std::vector<Vec3f> normals;
  // For a robot sample: the fraction of human eye positions around the robot that see the
  // point (0 = never visible: underside, enclosed, against the floor). See model_visibility.h.
  std::vector<float> visibility;

  std::size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  bool has_normals() const { return !normals.empty() && normals.size() == points.size(); }
  bool has_visibility() const { return !visibility.empty() && visibility.size() == points.size(); }
  // The points whose index is in `keep`, with their attributes.
  PointCloud Subset(const std::vector<std::uint32_t>& keep) const;
  void Transform(const Iso3& T_new_old);
};

// Axis-aligned bounding box of a point set; empty set gives min > max.
struct Aabb {
  Vec3f min = Vec3f::Constant(std::numeric_limits<float>::max());
  Vec3f max = Vec3f::Constant(std::numeric_limits<float>::lowest());
  void Extend(const Vec3f& p) { min = min.cwiseMin(p); max = max.cwiseMax(p); }
  bool valid() const { return (min.array() <= max.array()).all(); }
  bool Contains(const Vec3f& p) const { return (p.array() >= min.array()).all() && (p.array() <= max.array()).all(); }
  bool Overlaps(const Aabb& o) const { return (o.min.array() <= max.array()).all() && (min.array() <= o.max.array()).all(); }
  Aabb Grown(float margin) const { return {min.array() - margin, max.array() + margin}; }
};
Aabb BoundsOf(const std::vector<Vec3f>& points);
Vec3f Centroid(const TriangleMesh& mesh, const Triangle& t);

// Builds an isometry from translation + unit quaternion.
Iso3 MakePose(const Vec3& position, const Quat& orientation);
// Rotation about +z (gravity up) by yaw radians, then translation.
Iso3 MakeYawPose(double x, double y, double z, double yaw);
// Heading of T's x axis about +z, in radians in (-pi, pi]: the yaw MakeYawPose takes.
inline double YawOf(const Iso3& T) { return std::atan2(T.linear()(1, 0), T.linear()(0, 0)); }
// One degree in radians: angles written in degrees read 30 * kDegree.
inline constexpr double kDegree = std::numbers::pi / 180.0;
// An angle (radians) into (-pi, pi]: the difference of two yaws as a turn.
inline double WrapAngle(double a) {
  a = std::remainder(a, 2 * std::numbers::pi);
  return a <= -std::numbers::pi ? a + 2 * std::numbers::pi : a;
}

}  // namespace arref
