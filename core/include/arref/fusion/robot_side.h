// RobotSide: the robot's model side of registrations, built once per robot and joint state
// and shared by requests (the server caches it): its surface samples with their visibility,
// and the robot as a headset would mesh it (model_reconstruction.h) at each voxel size.
#pragma once

#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "arref/base/cancel.h"
#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/robot/robot_model.h"

namespace arref {

// Robot surface points with normals in its base frame, posed by joints, with the visibility
// of each point (model_visibility.h). Model side: reusable across requests.
Result<PointCloud> SampleRobot(const RobotModel& robot, const JointValues& joints, std::size_t samples,
                               std::uint64_t seed);
// The same from the robot's already posed mesh (base frame); name is for error messages.
Result<PointCloud> SamplePosedRobot(const TriangleMesh& mesh_base, const std::string& name, std::size_t samples,
                                    std::uint64_t seed);

// The robot side of registrations, built once per robot and joint state and shared by
// requests (the server caches it): the samples of SampleRobot, and the robot as a headset
// would mesh it (model_reconstruction.h), made on first use for each voxel size.
class RobotSide {
 public:
  // links: only these links' geometry (UnmovedLinks: a map made while the arm moved); null: all.
  static Result<std::shared_ptr<const RobotSide>> Create(const RobotModel& robot, const JointValues& joints,
                                                         std::size_t samples, std::uint64_t seed,
                                                         const std::set<std::string>* links = nullptr);
  const PointCloud& samples() const { return samples_; }
  // Made from some of the robot's links only (Create's links).
  bool partial() const { return partial_; }
  // Base frame height of the surface the robot stands on (RestingHeight, joint_motion.h).
  double resting_height() const { return resting_height_; }
  // Cached per millimetre of voxel size and walk; thread-safe. walk -1: all round; k in
  // [0, kWalks): a 216 degree arc centred at k * 360 / kWalks degrees. thinned_to > 0: at most
  // that many of its points (Thinned), as a method fits them. The first call for a voxel size
  // makes every walk's surface. A cancel while they are made returns Status::Cancelled and
  // keeps nothing: the next call makes them again.
  static constexpr int kWalks = 8;
  // Voxel sizes whose surfaces are kept, least recently used dropped first. A headset meshes at
  // one resolution (a spatial-mapping setting), so a session needs one or two; the bound keeps
  // a client sending meshes of ever new resolutions from growing the cache without end.
  // Surfaces a request still holds live on until it lets them go.
  static constexpr std::size_t kVoxelSizesKept = 4;
  Result<std::shared_ptr<const PointCloud>> Expected(double voxel_m, int walk = -1, std::size_t thinned_to = 0,
                                                     const CancelToken* cancel = nullptr) const;
  std::size_t voxel_sizes_kept() const;  // how many voxel sizes' surfaces the cache holds now
  // The samples a person can see (VisiblePoints), Thinned; cached, thread-safe.
  std::shared_ptr<const PointCloud> Visible(std::size_t thinned_to) const;
  // The same with the objects mapped round the robot, from the headset's mesh with the robot
  // at T_world_base (ExpectedSurfaceMaker::MakeInContext). Made anew on every call.
  // eyes_base: where the headset really was (base frame); empty: the walk's eyes. cancel is
  // polled between images and blocks of the fusion (Status::Cancelled).
  Result<PointCloud> ExpectedInContext(double voxel_m, int walk, const TriangleMesh& scene_world,
                                       const Iso3& T_world_base, const std::vector<Vec3>& eyes_base = {},
                                       const CancelToken* cancel = nullptr) const;
  // The eyes ExpectedInContext fuses from when it is given none (base frame).
  static std::vector<Vec3> RefitEyes(int walk);

 private:
  RobotSide(TriangleMesh mesh_base, PointCloud samples, std::uint64_t seed, bool partial, double resting_height);
  using ExpectedKey = std::tuple<long, int, std::size_t>;  // voxel in mm, walk, thinned_to
  Result<std::shared_ptr<const PointCloud>> ExpectedLocked(const ExpectedKey& key,
                                                           const CancelToken* cancel) const;  // under mutex_
  // Into expected_ or failed_, under mutex_; a cancel keeps nothing and returns Cancelled.
  Status MakeEveryWalk(long voxel_mm, const CancelToken* cancel) const;
  Result<std::shared_ptr<const ExpectedSurfaceMaker>> Maker() const;  // under mutex_
  void KeepRecentVoxelSizes(long used_mm) const;                       // under mutex_
  TriangleMesh mesh_base_;
  PointCloud samples_;
  std::uint64_t seed_;
  bool partial_ = false;
  double resting_height_ = 0.0;
  mutable std::mutex mutex_;
  mutable std::shared_ptr<const ExpectedSurfaceMaker> maker_;  // made on first use
  mutable std::map<ExpectedKey, std::shared_ptr<const PointCloud>> expected_;
  mutable std::map<ExpectedKey, Status> failed_;
  mutable std::vector<long> voxel_sizes_mm_;  // of expected_ and failed_, least recently used first
  mutable std::map<std::size_t, std::shared_ptr<const PointCloud>> visible_;
};

}  // namespace arref
