// Depth images of a triangle scene, ray cast with Embree (kept out of every other header).
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref {

// Pinhole camera in the optical convention: z forward, x right, y down. Pixel (u, v) covers
// [u, u+1) x [v, v+1); its ray goes through the pixel centre.
struct PinholeCamera {
  int width = 0;
  int height = 0;
  double focal_px = 0.0;  // square pixels

  static PinholeCamera FromFov(int width, int height, double fov_horizontal_deg);
  double cx() const { return 0.5 * width; }
  double cy() const { return 0.5 * height; }
  // Unit, camera frame. Inline: fusion and ray casting ask for every pixel of every view.
  Vec3 RayDirection(int u, int v) const {
    return Vec3((u + 0.5 - cx()) / focal_px, (v + 0.5 - cy()) / focal_px, 1.0).normalized();
  }
  // Pixel index hit by a camera-frame point, or -1 when behind the camera or off the image.
  // Inline and in float too: TSDF fusion calls it for every voxel of every view.
  template <class Scalar>
  int PixelOf(const Eigen::Matrix<Scalar, 3, 1>& p) const {
    if (p.z() <= Scalar(1e-6)) return -1;
    const Eigen::Matrix<Scalar, 2, 1> uv = Project(p);
    if (!(uv.x() >= 0 && uv.y() >= 0 && uv.x() < width && uv.y() < height)) return -1;
    return static_cast<int>(uv.y()) * width + static_cast<int>(uv.x());
  }
  // Image coordinates (pixels, continuous) of a camera-frame point in front of the camera.
  template <class Scalar>
  Eigen::Matrix<Scalar, 2, 1> Project(const Eigen::Matrix<Scalar, 3, 1>& p) const {
    return {static_cast<Scalar>(focal_px) * p.x() / p.z() + static_cast<Scalar>(cx()),
            static_cast<Scalar>(focal_px) * p.y() / p.z() + static_cast<Scalar>(cy())};
  }
};

// T_scene_camera of an optical camera at `eye` looking at `target`, image rows downwards in
// gravity (z up); looking straight down, x points along the scene's y.
Iso3 LookAt(const Vec3& eye, const Vec3& target);

// Range along each pixel's ray (row-major), 0 where nothing is hit within max_range.
using RangeImage = std::vector<float>;

// Which pixels of an image to trace (row-major, non-zero: traced).
using PixelMask = std::vector<std::uint8_t>;
// The pixels whose rays can pass through a box (scene frame): columns [u0, u1) of rows [v0, v1),
// the bounds of its corners' projections. The whole image when part of the box lies behind the
// camera; empty (u0 == u1 or v0 == v1) when the box is invalid or off the image.
struct PixelRect {
  int u0 = 0, u1 = 0, v0 = 0, v1 = 0;
};
PixelRect PixelsOfBox(const PinholeCamera& camera, const Iso3& T_camera_scene, const Aabb& box);

class RayCaster {
 public:
  // How Embree builds its BVH: kForTracing (its default) for scenes rendered from many views,
  // kForOneUse for a scene built per request: about 3x faster to build and a quarter slower to
  // trace, a net gain for a scene traced from one set of views (the refit in context).
  enum class Build { kForTracing, kForOneUse };
  // The scene is copied into Embree's buffers; the mesh may be dropped afterwards.
  static Result<RayCaster> Create(const TriangleMesh& scene, Build build = Build::kForTracing);
  // The scene plus everything `also` holds, which is traced through its own BVH as it stands
  // (an Embree instance): only the scene's BVH is built. Hits are those of one caster holding
  // both, at the same distances as `also` gives alone. `also` must outlive the result.
  static Result<RayCaster> Create(const TriangleMesh& scene, Build build, const RayCaster& also);
  RayCaster(RayCaster&&) noexcept;
  RayCaster& operator=(RayCaster&&) noexcept;
  ~RayCaster();

  // With `incidence`, also |cos| of the angle between each pixel's ray and the surface it hits
  // (0 where nothing is hit). With `traced`, only the pixels it marks are traced; the others
  // stay 0.
  RangeImage Render(const PinholeCamera& camera, const Iso3& T_scene_camera, double max_range_m,
                    std::vector<float>* incidence = nullptr, const PixelMask* traced = nullptr) const;

 private:
  struct Impl;
  explicit RayCaster(std::unique_ptr<Impl> impl);
  static Result<RayCaster> BuildScene(std::unique_ptr<Impl> impl, const TriangleMesh& mesh, Build build,
                                      const RayCaster* also);
  std::unique_ptr<Impl> impl_;
};

}  // namespace arref
