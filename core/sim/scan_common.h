// Pieces of the simulated scan shared by the cell simulator and the room simulator (private to
// arref_sim): depth noise, head-pose error, random streams, per-surface errors.
#pragma once

#include <cstdint>
#include <random>

#include "arref/base/geometry.h"
#include "arref/fusion/raycaster.h"
#include "arref/sim/cell_simulator.h"

namespace arref::sim::detail {

std::uint64_t SplitMix64(std::uint64_t x);
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

}  // namespace arref::sim::detail
