// The one place that converts between frame conventions (see README "Frames and units").
//
// Internal frame: ROS REP 103, right-handed, x forward, y left, z up, metres.
// Unity: left-handed, x right, y up, z forward, metres.
// Mapping (Unity ROS-TCP-Connector "FLU", ros-sharp):
//   p_ros = C p_unity with C = [[0,0,1],[-1,0,0],[0,1,0]]   i.e. (z, -x, y)
//   R_ros = C R_unity C^T; as quaternion (x,y,z,w): q_ros = (q.z, -q.x, q.y, -q.w)
// det C = -1, so this is a change of handedness: triangle winding flips.
#pragma once

#include <string_view>

#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref {

enum class FrameConvention { kRos, kUnity };

Result<FrameConvention> ParseFrameConvention(std::string_view name);  // "ros" | "unity"
const char* FrameConventionName(FrameConvention frame);

// The change-of-basis matrix C above.
const Eigen::Matrix3d& UnityToRosBasis();

Vec3 PositionToRos(const Vec3& p, FrameConvention from);
Vec3 PositionFromRos(const Vec3& p, FrameConvention to);
// Quaternions are (x, y, z, w) unit quaternions in the given convention.
Quat RotationToRos(const Quat& q, FrameConvention from);
Quat RotationFromRos(const Quat& q, FrameConvention to);
Iso3 PoseToRos(const Vec3& position, const Quat& orientation, FrameConvention from);
// Splits an internal pose into position and orientation of the given convention.
void PoseFromRos(const Iso3& T, FrameConvention to, Vec3* position, Quat* orientation);

// Converts vertices and flips triangle winding, so outward normals stay outward.
void MeshToRos(TriangleMesh& mesh, FrameConvention from);
void MeshFromRos(TriangleMesh& mesh, FrameConvention to);

}  // namespace arref
