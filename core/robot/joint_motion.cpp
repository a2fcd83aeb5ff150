#include "arref/robot/joint_motion.h"

#include <algorithm>
#include <numbers>

namespace arref {
namespace {

// A link moved when its pose differs beyond rounding (a joint's range is at least min_range).
bool Moved(const Iso3& a, const Iso3& b) { return (a.matrix() - b.matrix()).cwiseAbs().maxCoeff() > 1e-9; }

// How firmly a surface fixes the heading of a gravity-aligned fit: point-to-plane residuals
// over its triangles (area weighted) give the 4-DoF information matrix of (x, y, z, yaw), as
// in the normal equations of arref-icp; the yaw's information left after x, y and z are
// fitted too (a Schur complement), per square metre, is the root mean square of a moment arm
// (metres). A surface of revolution about the vertical gives 0: it leaves the yaw free.
double YawLeverage(const TriangleMesh& mesh) {
  Eigen::Matrix4d H = Eigen::Matrix4d::Zero();
  double area = 0;
  for (const Triangle& t : mesh.triangles) {
    const Vec3 a = mesh.vertices[t[0]].cast<double>(), b = mesh.vertices[t[1]].cast<double>(),
               c = mesh.vertices[t[2]].cast<double>();
    const Vec3 cross = (b - a).cross(c - a);
    const double w = cross.norm() / 2;
    if (w <= 0) continue;
    const Vec3 n = cross.normalized(), p = (a + b + c) / 3;
    Eigen::Vector4d J;
    J << n, Vec3::UnitZ().cross(p).dot(n);
    H += w * J * J.transpose();
    area += w;
  }
  if (area <= 0) return 0.0;
  const Eigen::Matrix3d Hxx = H.topLeftCorner<3, 3>();
  const Eigen::Vector3d Hxy = H.topRightCorner<3, 1>();
  const double yaw_info = H(3, 3) - Hxy.dot(Hxx.ldlt().solve(Hxy));
  return std::sqrt(std::max(0.0, yaw_info) / area);
}

}  // namespace

Result<std::set<std::string>> UnmovedLinks(const RobotModel& robot, const JointValues& at, const JointRanges& ranges,
                                           double min_range) {
  JointValues start;
  for (const JointInfo& j : robot.ActuatedJoints()) start[j.name] = 0.0;
  for (const auto& [name, value] : at)
    if (start.contains(name)) start[name] = value;
  for (const auto& [name, range] : ranges)
    if (!start.contains(name))
      return Status::InvalidArgument("robot '" + robot.name() + "' has no actuated joint '" + name + "'");
  start = robot.ClampedToLimits(start);
  ARREF_ASSIGN_OR_RETURN(const auto poses, robot.LinkPoses(start));
  const std::vector<std::string> links = robot.GeometryLinks();
  std::set<std::string> unmoved(links.begin(), links.end());
  for (const auto& [name, range] : ranges) {
    if (range.second - range.first <= min_range) continue;
    for (const double end : {range.first, range.second}) {
      JointValues q = start;
      q[name] = end;
      ARREF_ASSIGN_OR_RETURN(const auto moved, robot.LinkPoses(robot.ClampedToLimits(q)));
      std::erase_if(unmoved, [&](const std::string& link) { return Moved(poses.at(link), moved.at(link)); });
    }
  }
  return unmoved;
}

Result<std::set<std::string>> FixedLinks(const RobotModel& robot) {
  JointRanges every;
  for (const JointInfo& j : robot.ActuatedJoints())
    if (j.mimic_of.empty())  // a mimic joint moves with the joint it follows
      every[j.name] = j.has_limits ? std::pair{j.lower, j.upper} : std::pair{-std::numbers::pi / 2, std::numbers::pi / 2};
  return UnmovedLinks(robot, {}, every, 0.0);
}

Result<double> RestingHeight(const RobotModel& robot) {
  ARREF_ASSIGN_OR_RETURN(const std::set<std::string> fixed, FixedLinks(robot));
  if (fixed.empty()) return 0.0;
  // No joint moves these links, so any joint values pose them: the defaults.
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh base, robot.PosedMesh({}, fixed));
  return base.empty() ? 0.0 : std::min(0.0, static_cast<double>(BoundsOf(base.vertices).min.z()));
}

Result<MovingFit> ChooseMovingFit(const RobotModel& robot, const JointValues& at, const JointRanges& ranges,
                                  double min_range, double mesh_voxel_m, double min_leverage_voxels,
                                  double min_moved_share) {
  MovingFit fit;
  ARREF_ASSIGN_OR_RETURN(fit.unmoved, UnmovedLinks(robot, at, ranges, min_range));
  if (fit.unmoved.size() == robot.GeometryLinks().size()) return fit;  // nothing moved
  const JointValues q = robot.ClampedToLimits(at);
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh whole, robot.PosedMesh(q));
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh still, robot.PosedMesh(q, fit.unmoved));
  const double area = whole.SurfaceArea();
  fit.unmoved_area_share = area > 0 ? still.SurfaceArea() / area : 0.0;
  fit.yaw_leverage_m = YawLeverage(still);
  fit.much_moved = 1.0 - fit.unmoved_area_share >= min_moved_share;
  if (!fit.unmoved.empty() && fit.much_moved && fit.yaw_leverage_m >= min_leverage_voxels * mesh_voxel_m)
    fit.links = fit.unmoved;
  return fit;
}

}  // namespace arref
