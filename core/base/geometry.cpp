#include "arref/base/geometry.h"

namespace arref {

void TriangleMesh::Append(const TriangleMesh& other, const Iso3& T_this_other) {
  const auto offset = static_cast<std::uint32_t>(vertices.size());
  const Eigen::Isometry3f T = T_this_other.cast<float>();
  // No reserve of the exact new size: a mesh built from many parts (a map's 200 surfaces) would
  // then be copied whole on every append; push_back's doubling copies it about once.
  for (const auto& v : other.vertices) vertices.push_back(T * v);
  for (const auto& t : other.triangles) triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
}

void TriangleMesh::Transform(const Iso3& T_new_old) {
  const Eigen::Isometry3f T = T_new_old.cast<float>();
  for (auto& v : vertices) v = T * v;
}

double TriangleMesh::SurfaceArea() const {
  double area = 0.0;
  for (const auto& t : triangles) {
    const Vec3 a = vertices[t[0]].cast<double>();
    area += 0.5 * (vertices[t[1]].cast<double>() - a).cross(vertices[t[2]].cast<double>() - a).norm();
  }
  return area;
}

void PointCloud::Transform(const Iso3& T_new_old) {
  const Eigen::Isometry3f T = T_new_old.cast<float>();
  const Eigen::Matrix3f R = T.linear();
  for (auto& p : points) p = T * p;
  for (auto& n : normals) n = R * n;
}

PointCloud PointCloud::Subset(const std::vector<std::uint32_t>& keep) const {
  PointCloud out;
  out.points.reserve(keep.size());
  for (auto i : keep) out.points.push_back(points[i]);
  if (has_normals())
    for (auto i : keep) out.normals.push_back(normals[i]);
  if (has_visibility())
    for (auto i : keep) out.visibility.push_back(visibility[i]);
  return out;
}

Vec3f Centroid(const TriangleMesh& mesh, const Triangle& t) {
  return (mesh.vertices[t[0]] + mesh.vertices[t[1]] + mesh.vertices[t[2]]) / 3.0f;
}

Aabb BoundsOf(const std::vector<Vec3f>& points) {
  Aabb box;
  for (const auto& p : points) box.Extend(p);
  return box;
}

Iso3 MakePose(const Vec3& position, const Quat& orientation) {
  Iso3 T = Iso3::Identity();
  T.linear() = orientation.normalized().toRotationMatrix();
  T.translation() = position;
  return T;
}

Iso3 MakeYawPose(double x, double y, double z, double yaw) {
  return MakePose(Vec3(x, y, z), Quat(Eigen::AngleAxisd(yaw, Vec3::UnitZ())));
}

}  // namespace arref
