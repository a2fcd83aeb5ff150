#include "arref/fusion/raycaster.h"

#include <embree3/rtcore.h>
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>

#include "arref/fusion/embree_ray.h"

namespace arref {

Iso3 LookAt(const Vec3& eye, const Vec3& target) {
  const Vec3 forward = (target - eye).normalized();
  Vec3 right = forward.cross(Vec3::UnitZ());
  right = right.norm() > 1e-6 ? right.normalized() : Vec3::UnitY();  // looking straight down
  Iso3 T = Iso3::Identity();
  T.linear().col(0) = right;
  T.linear().col(1) = forward.cross(right);
  T.linear().col(2) = forward;
  T.translation() = eye;
  return T;
}

PinholeCamera PinholeCamera::FromFov(int width, int height, double fov_horizontal_deg) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.focal_px = 0.5 * width / std::tan(0.5 * fov_horizontal_deg * std::numbers::pi / 180.0);
  return c;
}

PixelRect PixelsOfBox(const PinholeCamera& camera, const Iso3& T_camera_scene, const Aabb& box) {
  if (!box.valid()) return {};
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::max()), hi = -lo;
  for (int c = 0; c < 8; ++c) {
    const Vec3 corner((c & 1 ? box.max : box.min).x(), (c & 2 ? box.max : box.min).y(), (c & 4 ? box.max : box.min).z());
    const Vec3 p = T_camera_scene * corner.cast<double>();
    if (p.z() <= 1e-6) return {0, camera.width, 0, camera.height};
    const Eigen::Vector2d uv = camera.Project(p);
    lo = lo.cwiseMin(uv), hi = hi.cwiseMax(uv);
  }
  // A point inside the box projects within its corners' bounds, onto the pixel at their floor.
  const auto clamp = [](double x, int n) { return static_cast<int>(std::clamp(std::floor(x), 0.0, double(n))); };
  return {clamp(lo.x(), camera.width), clamp(hi.x() + 1, camera.width), clamp(lo.y(), camera.height),
          clamp(hi.y() + 1, camera.height)};
}

struct RayCaster::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

RayCaster::RayCaster(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RayCaster::RayCaster(RayCaster&&) noexcept = default;
RayCaster& RayCaster::operator=(RayCaster&&) noexcept = default;
RayCaster::~RayCaster() = default;

Result<RayCaster> RayCaster::Create(const TriangleMesh& mesh, Build build) {
  auto impl = std::make_unique<Impl>();
  impl->device = rtcNewDevice(nullptr);
  if (!impl->device) return Status::Internal("ray casting: cannot create an Embree device");
  return BuildScene(std::move(impl), mesh, build, nullptr);
}

Result<RayCaster> RayCaster::Create(const TriangleMesh& mesh, Build build, const RayCaster& also) {
  auto impl = std::make_unique<Impl>();
  impl->device = also.impl_->device;  // an instanced scene must come from the same device
  rtcRetainDevice(impl->device);
  return BuildScene(std::move(impl), mesh, build, &also);
}

Result<RayCaster> RayCaster::BuildScene(std::unique_ptr<Impl> impl, const TriangleMesh& mesh, Build build,
                                        const RayCaster* also) {
  if (mesh.empty()) return Status::FailedPrecondition("ray casting: the scene has no triangles");
  const RTCBuildQuality quality = build == Build::kForOneUse ? RTC_BUILD_QUALITY_LOW : RTC_BUILD_QUALITY_MEDIUM;
  impl->scene = rtcNewScene(impl->device);
  rtcSetSceneBuildQuality(impl->scene, quality);
  AttachTriangles(impl->device, impl->scene, mesh, quality);
  if (also) {
    RTCGeometry instance = rtcNewGeometry(impl->device, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(instance, also->impl_->scene);
    const float identity[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};  // 3x4, column major
    rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, identity);
    rtcCommitGeometry(instance);
    rtcAttachGeometry(impl->scene, instance);
    rtcReleaseGeometry(instance);
  }
  rtcCommitScene(impl->scene);
  if (const RTCError err = rtcGetDeviceError(impl->device); err != RTC_ERROR_NONE)
    return Status::Internal("ray casting: Embree error " + std::to_string(static_cast<int>(err)) +
                            " building a scene of " + std::to_string(mesh.triangles.size()) + " triangles");
  spdlog::debug("Embree scene with {} triangles{}", mesh.triangles.size(), also ? " and an instance" : "");
  return RayCaster(std::move(impl));
}

RangeImage RayCaster::Render(const PinholeCamera& camera, const Iso3& T_scene_camera, double max_range_m,
                             std::vector<float>* incidence, const PixelMask* traced) const {
  RangeImage range(static_cast<std::size_t>(camera.width) * camera.height, 0.0f);
  if (incidence) incidence->assign(range.size(), 0.0f);
  const Eigen::Matrix3d R = T_scene_camera.linear();
  const Vec3 origin = T_scene_camera.translation();
  tbb::parallel_for(0, camera.height, [&](int v) {
    const std::size_t row = static_cast<std::size_t>(v) * camera.width;
    TraceRow(
        impl_->scene, origin, max_range_m, 0, camera.width,
        [&](int u, Vec3* dir) {
          if (traced && !(*traced)[row + u]) return false;
          *dir = R * camera.RayDirection(u, v);
          return true;
        },
        [&](int u, const Vec3& dir, float distance, const Vec3& normal, unsigned) {
          range[row + u] = distance;
          if (incidence) (*incidence)[row + u] = static_cast<float>(std::abs(normal.normalized().dot(dir)));
        });
  });
  return range;
}

}  // namespace arref
