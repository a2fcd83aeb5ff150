// A robot described by a URDF: its links' geometry and its kinematic tree.
#pragma once

#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref {

enum class GeometryKind { kVisual, kCollision };

struct RobotLoadOptions {
  // Folders searched for package://PKG/... URIs: each is the package itself (its folder is
  // named PKG) or contains it (like an entry of ROS_PACKAGE_PATH).
  std::vector<std::string> package_path;
  GeometryKind geometry = GeometryKind::kVisual;
};

enum class JointType { kFixed, kRevolute, kContinuous, kPrismatic };

struct JointInfo {
  std::string name;
  JointType type = JointType::kFixed;
  double lower = 0.0;  // limits (rad or m); continuous joints have none
  double upper = 0.0;
  bool has_limits = false;
  std::string mimic_of;  // non-empty for a mimic joint: value = multiplier * other + offset
  double mimic_multiplier = 1.0;
  double mimic_offset = 0.0;
};

using JointValues = std::map<std::string, double>;  // by joint name; rad or m

class RobotModel {
 public:
  static Result<RobotModel> Load(const std::string& urdf_path, const RobotLoadOptions& options = {});
  // Parses URDF text; relative mesh paths resolve against base_dir.
  static Result<RobotModel> FromString(const std::string& urdf_xml, const std::string& base_dir,
                                       const RobotLoadOptions& options = {});

  RobotModel(RobotModel&&) noexcept;
  RobotModel& operator=(RobotModel&&) noexcept;
  ~RobotModel();

  const std::string& name() const;
  const std::string& root_link() const;
  // Joints a caller may set (not fixed, not mimic), in tree order.
  std::vector<JointInfo> ActuatedJoints() const;

  // Fills unnamed actuated joints with 0 (clamped into limits), derives mimic joints, and
  // rejects unknown names, non-finite values and values outside limits.
  Result<JointValues> CompleteJoints(const JointValues& given) const;
  // The given joints that have limits moved into them (names it does not know left for
  // CompleteJoints to reject): a state interpolated or extrapolated between samples at a limit
  // can overshoot it by a little.
  JointValues ClampedToLimits(const JointValues& given) const;

  // Forward kinematics: T_root_link for every link.
  Result<std::map<std::string, Iso3>> LinkPoses(const JointValues& joints) const;

  // The posed robot as one mesh in the root (base) frame.
  Result<TriangleMesh> PosedMesh(const JointValues& joints) const;
  // The same with only the named links' geometry; a name the robot does not hold is an error.
  Result<TriangleMesh> PosedMesh(const JointValues& joints, const std::set<std::string>& links) const;
  // The links that carry geometry, by name.
  std::vector<std::string> GeometryLinks() const;

  // Geometry of one link in its own frame (all its visuals or collisions).
  const TriangleMesh* LinkMesh(const std::string& link) const;

 private:
  struct Impl;
  explicit RobotModel(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Resolves a URDF mesh reference to an existing file: package://PKG/rel (searched in
// package_path), file:///abs, /abs, or relative to urdf_dir. The error names the URI and
// every place it looked.
Result<std::string> ResolveMeshUri(const std::string& uri, const std::string& urdf_dir,
                                   const std::vector<std::string>& package_path);

// Loads a mesh file (STL, COLLADA, OBJ, PLY, ...) with assimp into metres as stored,
// applying the file's own node transforms.
Result<TriangleMesh> LoadMeshFile(const std::string& path);

// Writes a mesh as binary PLY, binary STL or OBJ, chosen by the file's extension.
Status SaveMeshFile(const TriangleMesh& mesh, const std::string& path);

}  // namespace arref
