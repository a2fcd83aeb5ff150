#include "arref/base/frames.h"

#include <utility>

namespace arref {

Result<FrameConvention> ParseFrameConvention(std::string_view name) {
  if (name == "ros") return FrameConvention::kRos;
  if (name == "unity") return FrameConvention::kUnity;
  return Status::InvalidArgument("unknown frame convention '" + std::string(name) +
                                 "' (expected 'ros' or 'unity')");
}

const char* FrameConventionName(FrameConvention frame) {
  return frame == FrameConvention::kRos ? "ros" : "unity";
}

const Eigen::Matrix3d& UnityToRosBasis() {
  static const Eigen::Matrix3d C = (Eigen::Matrix3d() << 0, 0, 1, -1, 0, 0, 0, 1, 0).finished();
  return C;
}

Vec3 PositionToRos(const Vec3& p, FrameConvention from) {
  return from == FrameConvention::kRos ? p : Vec3(UnityToRosBasis() * p);
}

Vec3 PositionFromRos(const Vec3& p, FrameConvention to) {
  return to == FrameConvention::kRos ? p : Vec3(UnityToRosBasis().transpose() * p);
}

// Conjugating by C (R_ros = C R C^T) is equivalent to the quaternion formula in the
// header; going through matrices keeps one formula to test.
Quat RotationToRos(const Quat& q, FrameConvention from) {
  if (from == FrameConvention::kRos) return q.normalized();
  const Eigen::Matrix3d& C = UnityToRosBasis();
  return Quat(C * q.normalized().toRotationMatrix() * C.transpose()).normalized();
}

Quat RotationFromRos(const Quat& q, FrameConvention to) {
  if (to == FrameConvention::kRos) return q.normalized();
  const Eigen::Matrix3d& C = UnityToRosBasis();
  return Quat(C.transpose() * q.normalized().toRotationMatrix() * C).normalized();
}

Iso3 PoseToRos(const Vec3& position, const Quat& orientation, FrameConvention from) {
  return MakePose(PositionToRos(position, from), RotationToRos(orientation, from));
}

void PoseFromRos(const Iso3& T, FrameConvention to, Vec3* position, Quat* orientation) {
  *position = PositionFromRos(T.translation(), to);
  *orientation = RotationFromRos(Quat(T.rotation()), to);
}

namespace {
void ConvertMesh(TriangleMesh& mesh, const Eigen::Matrix3f& M) {
  for (auto& v : mesh.vertices) v = M * v;
  for (auto& t : mesh.triangles) std::swap(t[1], t[2]);  // handedness change flips winding
}
}  // namespace

void MeshToRos(TriangleMesh& mesh, FrameConvention from) {
  if (from == FrameConvention::kRos) return;
  ConvertMesh(mesh, UnityToRosBasis().cast<float>());
}

void MeshFromRos(TriangleMesh& mesh, FrameConvention to) {
  if (to == FrameConvention::kRos) return;
  ConvertMesh(mesh, UnityToRosBasis().transpose().cast<float>());
}

}  // namespace arref
