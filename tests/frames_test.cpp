#include <gtest/gtest.h>

#include <random>

#include "arref/base/frames.h"

namespace arref {
namespace {

Quat RandomRotation(std::mt19937_64& rng) {
  std::normal_distribution<double> n;
  return Quat(n(rng), n(rng), n(rng), n(rng)).normalized();
}

TEST(Frames, UnityAxesMapToRosAxes) {
  // Unity forward (+z) is ROS forward (+x); Unity right (+x) is ROS -y; Unity up (+y) is ROS up (+z).
  EXPECT_TRUE(PositionToRos(Vec3(0, 0, 1), FrameConvention::kUnity).isApprox(Vec3(1, 0, 0)));
  EXPECT_TRUE(PositionToRos(Vec3(1, 0, 0), FrameConvention::kUnity).isApprox(Vec3(0, -1, 0)));
  EXPECT_TRUE(PositionToRos(Vec3(0, 1, 0), FrameConvention::kUnity).isApprox(Vec3(0, 0, 1)));
  EXPECT_DOUBLE_EQ(UnityToRosBasis().determinant(), -1.0);
}

TEST(Frames, QuaternionMatchesPublishedFormula) {
  // q_ros = (q.z, -q.x, q.y, -q.w) of q_unity (ROS-TCP-Connector), equal up to sign.
  std::mt19937_64 rng(3);
  for (int i = 0; i < 100; ++i) {
    const Quat qu = RandomRotation(rng);
    const Quat expected(-qu.w(), qu.z(), -qu.x(), qu.y());
    const Quat got = RotationToRos(qu, FrameConvention::kUnity);
    EXPECT_NEAR(std::abs(got.dot(expected)), 1.0, 1e-9);
  }
}

TEST(Frames, RotationConvertsLikePointsDo) {
  // Rotating a point in Unity then converting equals converting then rotating in ROS.
  std::mt19937_64 rng(4);
  for (int i = 0; i < 100; ++i) {
    const Quat qu = RandomRotation(rng);
    const Vec3 pu(1.0 * i, -0.5, 2.0);
    const Vec3 via_unity = PositionToRos(qu * pu, FrameConvention::kUnity);
    const Vec3 via_ros = RotationToRos(qu, FrameConvention::kUnity) * PositionToRos(pu, FrameConvention::kUnity);
    EXPECT_TRUE(via_unity.isApprox(via_ros, 1e-9));
  }
}

TEST(Frames, UnityYawIsRosYawReversed) {
  // A left-handed yaw of +90 deg about up (turning right) is a right-handed yaw of -90 deg.
  const Quat qu(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitY()));
  const Quat qr = RotationToRos(qu, FrameConvention::kUnity);
  EXPECT_NEAR(std::abs(qr.dot(Quat(Eigen::AngleAxisd(-M_PI / 2, Vec3::UnitZ())))), 1.0, 1e-12);
}

TEST(Frames, RoundTripsArePrecise) {
  std::mt19937_64 rng(5);
  for (int i = 0; i < 50; ++i) {
    const Quat q = RandomRotation(rng);
    const Vec3 p(0.3 * i, -1.2, 0.7);
    const Iso3 T = PoseToRos(p, q, FrameConvention::kUnity);
    Vec3 p2;
    Quat q2;
    PoseFromRos(T, FrameConvention::kUnity, &p2, &q2);
    EXPECT_TRUE(p2.isApprox(p, 1e-12));
    EXPECT_NEAR(std::abs(q2.dot(q)), 1.0, 1e-12);
    PoseFromRos(T, FrameConvention::kRos, &p2, &q2);
    EXPECT_TRUE(p2.isApprox(T.translation()));
  }
}

TEST(Frames, MeshConversionKeepsNormalsOutward) {
  // A triangle facing Unity up (+y), clockwise seen from above as Unity draws front faces.
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {0, 0, 1}, {1, 0, 0}};
  mesh.triangles = {{0, 1, 2}};
  const Vec3f unity_normal = (mesh.vertices[1] - mesh.vertices[0]).cross(mesh.vertices[2] - mesh.vertices[0]);
  ASSERT_GT(unity_normal.y(), 0);  // in left-handed terms this is the clockwise front face, normal up
  MeshToRos(mesh, FrameConvention::kUnity);
  const Vec3f n = (mesh.vertices[mesh.triangles[0][1]] - mesh.vertices[mesh.triangles[0][0]])
                      .cross(mesh.vertices[mesh.triangles[0][2]] - mesh.vertices[mesh.triangles[0][0]]);
  EXPECT_GT(n.z(), 0) << "the face must still point up (ROS +z) after the handedness change";
  MeshFromRos(mesh, FrameConvention::kUnity);
  EXPECT_TRUE(mesh.vertices[1].isApprox(Vec3f(0, 0, 1)) || mesh.vertices[2].isApprox(Vec3f(0, 0, 1)));
  EXPECT_EQ(mesh.triangles[0], (Triangle{0, 1, 2}));
}

TEST(Frames, ParseNames) {
  EXPECT_EQ(*ParseFrameConvention("unity"), FrameConvention::kUnity);
  EXPECT_EQ(*ParseFrameConvention("ros"), FrameConvention::kRos);
  const auto bad = ParseFrameConvention("enu");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("enu"), std::string::npos);
}

}  // namespace
}  // namespace arref
