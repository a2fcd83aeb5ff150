// The exact robot model as a camera sees it, posed per frame: one Embree BVH per link, built
// once, under a top-level scene of instances whose transforms change with the joints. Posing
// costs the forward kinematics and a top-level rebuild over a handful of instances
// (microseconds), so a frame's model side is the ray cast alone.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/robot/robot_model.h"

namespace arref {

// A pinhole depth camera in the optical convention (x right, y down, z forward), pixels
// (u, v) with centres at u + 0.5, v + 0.5 like PinholeCamera.
struct DepthIntrinsics {
  int width = 0;
  int height = 0;
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
  static DepthIntrinsics FromFov(int width, int height, double fov_horizontal_deg);
  bool valid() const { return width > 0 && height > 0 && fx > 0 && fy > 0; }
  // Camera-frame direction with z = 1 (a z-depth times it is the point).
  Vec3 Ray(double u, double v) const { return {(u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1.0}; }
};

// What the model shows a camera: per traced pixel, the z-depth of the first hit (0: none);
// the hit points and their normals (facing the camera) in the robot's base frame.
struct ModelView {
  int width = 0, height = 0, stride = 1;  // the traced grid: every stride-th pixel in u and v
  std::vector<float> z_depth;            // (height / stride) x (width / stride), row-major
  PointCloud points_base;                // the hits, in no particular pixel order
  Aabb bounds_base;                      // of the posed model
};

class ModelCaster {
 public:
  static Result<ModelCaster> Create(const RobotModel& robot);
  ModelCaster(ModelCaster&&) noexcept;
  ModelCaster& operator=(ModelCaster&&) noexcept;
  ~ModelCaster();

  // Sets every link's pose (forward kinematics of complete joint values) and its bounds.
  Status Pose(const RobotModel& robot, const JointValues& joints);
  const Aabb& bounds_base() const;
  // Traces every stride-th pixel whose ray can pass through the posed model's bounds.
  ModelView Render(const DepthIntrinsics& camera, const Iso3& T_base_camera, double max_range_m, int stride) const;

 private:
  struct Impl;
  explicit ModelCaster(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace arref
