// Pieces of the simulated scan shared by the cell simulator and the room simulator (private to
// arref_sim): depth noise, head-pose error, random streams, per-surface errors.
#pragma once

#include <cstdint>
#include <functional>
#include <random>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/split_mix.h"
#include "arref/base/status.h"
#include "arref/fusion/raycaster.h"
#include "arref/sim/cell_simulator.h"

namespace arref::sim::detail {

// Long-throw depth runs at a few frames per second: time between the path's views.
constexpr double kSecondsPerView = 0.5;
constexpr double kNoiseSigmasInBand = 6.0;  // TSDF truncation of at least this many depth sigmas

// Counter-based Gaussian: a pixel's noise depends only on (seed, view, pixel).
double HashGaussian(std::uint64_t seed, std::uint64_t view, std::uint64_t pixel);
// Gaussian noise of scan.depth_noise_m along every ray of the image (view-th image of a scan).
void AddRangeNoise(RangeImage& range, const ScanOptions& scan, std::uint64_t seed, int view);
// A head-tracking error of scan.pose_jitter_m / _deg, in the camera frame.
Iso3 RandomJitter(const ScanOptions& scan, std::mt19937_64& rng);
// A random stream of its own per (seed, purpose).
std::mt19937_64 Stream(std::uint64_t seed, std::uint64_t purpose);
// A surface's rigid error up to the device's maxima, about `centre`.
Iso3 SurfaceError(const DeviceVariation& device, const Vec3& centre, std::mt19937_64& rng);
bool HasArea(const TriangleMesh& mesh);

// The surface cube at `corner` (world, a multiple of the surface size): which of the device's
// update times meshed it, and the head-pose error it was moved by then. One draw per cube, so
// the mesher and the measure of what it did to the robot agree.
struct CubeError {
  int time_index = 0;
  Iso3 T_moved_true = Iso3::Identity();
};
CubeError ErrorOfCube(const DeviceVariation& device, const Vec3& corner, double size, int updates, std::uint64_t rng_seed);
// The per-surface head-pose errors of the device's mesher at a world point (ErrorOfCube, the
// draw the mesher made), for MeshImprint::Motion.
std::function<Iso3(const Vec3&)> SurfaceErrors(const DeviceVariation& device, std::uint64_t rng_seed);
// A robot sample is seen by a view (MeshImprint::AddView) when the range at its pixel lies this
// close to it: a few depth sigmas and the sampling's spacing.
double SeenTolerance(const ScanOptions& scan);

// The device's mesher on a walk's range images: Open3D's TSDF fused up to each update time (over
// the walk's last third), cut into surface cubes that are each meshed at their own time (the
// spatial mapper re-meshes a surface when it changes, Microsoft's "Spatial mapping" guide), moved
// by the head-pose error of that time (ErrorOfCube), decimated to the device's density on their
// own and quantised.
Result<std::vector<Surface>> MeshLikeTheDevice(const PinholeCamera& camera, const std::vector<Iso3>& T_world_camera,
                                               const std::vector<RangeImage>& ranges, const DeviceVariation& device,
                                               double max_range_m, std::uint64_t rng_seed);

}  // namespace arref::sim::detail
