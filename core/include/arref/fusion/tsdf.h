// Sparse TSDF volume: projective fusion of range images and Naive Surface Nets extraction,
// the way a headset's spatial mapper turns noisy depth into a coarse, hole-riddled mesh.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <unordered_map>
#include <vector>

#include "arref/base/cancel.h"
#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/fusion/raycaster.h"

namespace arref {

struct TsdfOptions {
  double voxel_m = 0.03;
  double truncation_m = 0.09;
  Vec3 crop_center = Vec3::Zero();  // only blocks within crop_radius_m of it are allocated
  double crop_radius_m = 3.0;
  // When given, blocks are allocated only within near_margin_m of these points too: the band
  // round one object's surface, without the rest of the scene's (the points must outlive the
  // volume's constructor, which reads them).
  const std::vector<Vec3f>* near_points = nullptr;
  double near_margin_m = 0.0;
  // With near_points: only voxels within near_margin_m and one voxel of them are updated
  // (VoxelRows), not all of each near block; the rest stays unseen and meshes nothing.
  bool near_voxels_only = false;
  // The voxel update in single precision: about a fifth faster, and a voxel is millimetres
  // (float resolves micrometres at 10 m), but rounding differs from the double one's.
  bool single_precision = false;
  std::size_t max_blocks = 400000;  // ~1.6 GB of voxels: beyond that the options are unreasonable
};

class VoxelRows;

class TsdfVolume {
 public:
  static constexpr int kBlock = 8;  // voxels per block edge

  explicit TsdfVolume(const TsdfOptions& options);

  // Fuses one range image taken from T_volume_camera (the pose the mapper believes, which
  // need not be the pose the image was really taken from).
  // incidence: per pixel |cos| between ray and surface (RayCaster::Render). The distance along
  // a ray overstates the distance to a slanted surface by 1/cos; without the correction the
  // overstated positive side of grazing views drags horizontal surfaces ~5 mm down.
  Status Integrate(const PinholeCamera& camera, const Iso3& T_volume_camera, const RangeImage& range,
                   const std::vector<float>& incidence);
  // The same with the image's BandBlocks already known (they depend on the options, not on
  // what the volume holds): an image fused into several volumes needs them once.
  Status Integrate(const PinholeCamera& camera, const Iso3& T_volume_camera, const RangeImage& range,
                   const std::vector<float>& incidence, const std::vector<Eigen::Vector3i>& band);

  // One image as Integrate takes it.
  struct Image {
    Iso3 T_volume_camera;
    const RangeImage* range = nullptr;
    const std::vector<float>* incidence = nullptr;
    const std::vector<Eigen::Vector3i>* band = nullptr;  // its BandBlocks if known, else found here
  };
  // Fuses the images in order, bit for bit as one Integrate per image would. Each block is
  // updated by all its images in one task, while it is in cache, not once per image.
  // cancel is polled between images' allocations and before each block's update; once it is
  // cancelled the volume is left part fused and Status::Cancelled returned.
  Status IntegrateAll(const PinholeCamera& camera, const std::vector<Image>& images,
                      const CancelToken* cancel = nullptr);

  // The blocks within the truncation band of an image's measured pixels and the crop, each
  // once, in the order Integrate allocates them. With `allocating`, only those it would add
  // (near and not yet there), tested in parallel: after the first views nearly every block is.
  static std::vector<Eigen::Vector3i> BandBlocks(const TsdfOptions& options, const PinholeCamera& camera,
                                                 const Iso3& T_volume_camera, const RangeImage& range,
                                                 const TsdfVolume* allocating = nullptr);

  // Naive Surface Nets in the volume frame: a vertex per sign-changing cell, a quad per
  // sign-changing edge, only where every voxel involved was observed. Counter-clockwise
  // winding faces free space.
  TriangleMesh ExtractMesh() const;

  std::size_t block_count() const { return blocks_.size(); }
  // The pixels of an image from T_volume_camera whose rays pass a block that near_points let
  // the volume hold: no other pixel changes a voxel. Every pixel without near_points.
  PixelMask NearPixels(const PinholeCamera& camera, const Iso3& T_volume_camera) const;

 struct Voxel {
    float d = 0.0f;  // truncated signed distance / truncation: +1 free, < 0 behind the surface
    float w = 0.0f;  // observation weight, 0 = never seen
  };
  struct Block {
    Eigen::Vector3i index;
    std::vector<Voxel> voxels;  // kBlock^3, x fastest
    std::uint64_t rows = ~std::uint64_t{0};  // the rows it updates: bit y + kBlock * z (VoxelRows)
  };
  using Key = std::uint64_t;
  using NeighbourTable = std::array<int, 27>;

 private:

  static Key KeyOf(const Eigen::Vector3i& block);
  static Eigen::Vector3i BlockOf(const Vec3& p, double voxel_m);
  Eigen::Vector3i BlockOf(const Vec3& p) const { return BlockOf(p, options_.voxel_m); }
  void MarkNearBlocks(const std::vector<Vec3f>& points);
  Status Allocate(const std::vector<Eigen::Vector3i>& band);
  bool WouldAllocate(const Eigen::Vector3i& block) const;
  // Of the blocks near options_.near_points: far, near and not yet allocated, allocated.
  enum class Near : std::uint8_t { kFar, kFree, kAllocated };
  // Calls fn(box) with the bounds of every near block, or of those not yet allocated.
  template <class Fn>
  void ForEachNearBlock(bool free_only, Fn&& fn) const;
  // Per pixel, the depths along its ray (distance from the camera) between which it can pass a
  // near block not yet allocated; nearest > farthest where it passes none.
  struct DepthWindow {
    std::vector<float> nearest, farthest;
  };
  DepthWindow FreeBlockDepths(const PinholeCamera& camera, const Iso3& T_volume_camera) const;
  template <class Scalar>
  void UpdateVoxels(Block& block, const PinholeCamera& camera, const Eigen::Matrix<Scalar, 3, 1>& origin,
                    const Eigen::Matrix<Scalar, 3, 3>& step, const RangeImage& range,
                    const std::vector<float>& incidence) const;
  void UpdateVoxelsFast(Block& block, const PinholeCamera& camera, const Vec3f& origin, const Eigen::Matrix3f& step,
                        const RangeImage& range, const std::vector<float>& incidence) const;
  static bool OffImage(const PinholeCamera& camera, const Vec3f& origin, const Eigen::Matrix3f& step);
  void UpdateBlock(Block& block, const PinholeCamera& camera, const Iso3& T_camera_volume,
                   const RangeImage& range, const std::vector<float>& incidence) const;
  // For each block, its 27 neighbours (self at 13) as indices into blocks_, -1 if absent.
  std::vector<NeighbourTable> Neighbours() const;
  // Voxel at local coordinates in [-1, kBlock] of the block whose neighbours are nb.
  const Voxel* VoxelAt(const NeighbourTable& nb, int x, int y, int z) const;
  void CellVertices(int block, const NeighbourTable& nb, std::vector<int>& cell_vertex,
                    std::vector<Vec3f>& vertices) const;
  void CellQuads(int block, const NeighbourTable& nb, const std::vector<std::vector<int>>& cell_vertex,
                 const std::vector<std::uint32_t>& first_vertex, const std::vector<Vec3f>& vertices,
                 std::vector<Triangle>& triangles) const;

  TsdfOptions options_;
  std::deque<Block> blocks_;
  std::unordered_map<Key, int> index_;
  bool near_only_ = false;
  std::shared_ptr<const VoxelRows> near_rows_;  // options_.near_voxels_only's
  // The blocks near options_.near_points, if given, over their bounds [lo, hi], each Near.
  struct NearGrid {
    Eigen::Vector3i lo = Eigen::Vector3i::Zero(), hi = Eigen::Vector3i::Zero();
    std::vector<Near> slot;
    std::ptrdiff_t Offset(const Eigen::Vector3i& block) const;  // into slot; -1 outside [lo, hi]
  };
  NearGrid near_;
};

// The voxels of a TSDF grid (TsdfVolume's) within a radius of some points, as rows along x: a
// volume that holds one object's band (TsdfOptions::near_voxels_only) updates those only, not
// every voxel of each block that touches the band (round the built-in robot's links at 35 mm
// voxels, 52 % of those blocks' rows). A superset: each point counts as the centre of its voxel,
// the radius grown by half the voxel's diagonal.
class VoxelRows {
 public:
  static VoxelRows Of(const std::vector<Vec3f>& points, double voxel_m, double radius_m);
  // Bit y + kBlock * z is set when row (y, z) of the block (its voxels x = 0..kBlock-1) holds such a
  // voxel; 0 for a block beyond the radius.
  std::uint64_t RowsOf(const Eigen::Vector3i& block) const;

 private:
  static_assert(TsdfVolume::kBlock * TsdfVolume::kBlock <= 64, "a block's rows must fit one 64-bit mask");
  std::size_t Slot(const Eigen::Vector3i& from_lo) const;  // into rows_, of a block lo_ + from_lo
  Eigen::Vector3i lo_ = Eigen::Vector3i::Zero(), dims_ = Eigen::Vector3i::Zero();  // blocks
  std::vector<std::uint64_t> rows_;
};

}  // namespace arref
