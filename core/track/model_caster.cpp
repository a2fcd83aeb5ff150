#include "arref/track/model_caster.h"

#include <embree3/rtcore.h>
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "arref/fusion/embree_ray.h"

namespace arref {

DepthIntrinsics DepthIntrinsics::FromFov(int width, int height, double fov_horizontal_deg) {
  DepthIntrinsics c;
  c.width = width, c.height = height;
  c.fx = c.fy = 0.5 * width / std::tan(0.5 * fov_horizontal_deg * std::numbers::pi / 180.0);
  c.cx = 0.5 * width, c.cy = 0.5 * height;
  return c;
}

struct ModelCaster::Impl {
  RTCDevice device = nullptr;
  RTCScene top = nullptr;
  struct Link {
    std::string name;
    RTCScene scene = nullptr;
    RTCGeometry instance = nullptr;  // owned by top
    Aabb bounds_link;
    Iso3 T_base_link = Iso3::Identity();
  };
  std::vector<Link> links;
  Aabb bounds_base;
  ~Impl() {
    if (top) rtcReleaseScene(top);
    for (Link& l : links)
      if (l.scene) rtcReleaseScene(l.scene);
    if (device) rtcReleaseDevice(device);
  }
};

ModelCaster::ModelCaster(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ModelCaster::ModelCaster(ModelCaster&&) noexcept = default;
ModelCaster& ModelCaster::operator=(ModelCaster&&) noexcept = default;
ModelCaster::~ModelCaster() = default;

namespace {

RTCScene BuildLinkScene(RTCDevice device, const TriangleMesh& mesh) {
  RTCScene scene = rtcNewScene(device);
  AttachTriangles(device, scene, mesh, RTC_BUILD_QUALITY_MEDIUM);  // Embree's default quality
  rtcCommitScene(scene);
  return scene;
}

void SetTransform(RTCGeometry instance, const Iso3& T) {
  const Eigen::Matrix<float, 3, 4> m = T.matrix().topRows<3>().cast<float>();  // column major
  rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, m.data());
  rtcCommitGeometry(instance);
}

}  // namespace

Result<ModelCaster> ModelCaster::Create(const RobotModel& robot) {
  ARREF_ASSIGN_OR_RETURN(const auto poses, robot.LinkPoses({}));
  auto impl = std::make_unique<Impl>();
  impl->device = rtcNewDevice(nullptr);
  if (!impl->device) return Status::Internal("model caster: cannot create an Embree device");
  impl->top = rtcNewScene(impl->device);
  // The instances move every frame: a fast top-level build beats a good one.
  rtcSetSceneBuildQuality(impl->top, RTC_BUILD_QUALITY_LOW);
  rtcSetSceneFlags(impl->top, RTC_SCENE_FLAG_DYNAMIC);
  for (const auto& [name, T] : poses) {
    const TriangleMesh* mesh = robot.LinkMesh(name);
    if (!mesh || mesh->empty()) continue;
    Impl::Link link;
    link.name = name;
    link.scene = BuildLinkScene(impl->device, *mesh);
    link.bounds_link = BoundsOf(mesh->vertices);
    link.instance = rtcNewGeometry(impl->device, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(link.instance, link.scene);
    SetTransform(link.instance, T);
    rtcAttachGeometryByID(impl->top, link.instance, static_cast<unsigned>(impl->links.size()));
    rtcReleaseGeometry(link.instance);  // the top scene holds it
    impl->links.push_back(std::move(link));
  }
  if (impl->links.empty()) return Status::FailedPrecondition("model caster: robot '" + robot.name() + "' has no geometry");
  rtcCommitScene(impl->top);
  if (const RTCError err = rtcGetDeviceError(impl->device); err != RTC_ERROR_NONE)
    return Status::Internal("model caster: Embree error " + std::to_string(static_cast<int>(err)));
  ModelCaster caster(std::move(impl));
  ARREF_RETURN_IF_ERROR(caster.Pose(robot, {}));
  spdlog::debug("model caster: {} links of robot {}", caster.impl_->links.size(), robot.name());
  return caster;
}

Status ModelCaster::Pose(const RobotModel& robot, const JointValues& joints) {
  ARREF_ASSIGN_OR_RETURN(const auto poses, robot.LinkPoses(joints));
  Aabb bounds;
  for (Impl::Link& link : impl_->links) {
    const auto it = poses.find(link.name);
    if (it == poses.end()) return Status::Internal("model caster: link '" + link.name + "' has no pose");
    link.T_base_link = it->second;
    SetTransform(link.instance, link.T_base_link);
    const Aabb& b = link.bounds_link;
    for (int c = 0; c < 8; ++c) {
      const Vec3 corner((c & 1 ? b.max : b.min).x(), (c & 2 ? b.max : b.min).y(), (c & 4 ? b.max : b.min).z());
      bounds.Extend((link.T_base_link * corner).cast<float>());
    }
  }
  impl_->bounds_base = bounds;
  rtcCommitScene(impl_->top);
  return Status::Ok();
}

const Aabb& ModelCaster::bounds_base() const { return impl_->bounds_base; }

ModelView ModelCaster::Render(const DepthIntrinsics& camera, const Iso3& T_base_camera, double max_range_m,
                              int stride) const {
  ModelView view;
  stride = std::max(1, stride);
  view.width = camera.width, view.height = camera.height, view.stride = stride;
  view.bounds_base = impl_->bounds_base;
  const int gw = camera.width / stride, gh = camera.height / stride;
  view.z_depth.assign(static_cast<std::size_t>(gw) * gh, 0.0f);
  // Only the rows and columns the model's bounds can cover.
  const Iso3 T_camera_base = T_base_camera.inverse();
  double u0 = camera.width, u1 = 0, v0 = camera.height, v1 = 0;
  const Aabb& b = impl_->bounds_base;
  bool behind = false;
  for (int c = 0; c < 8; ++c) {
    const Vec3 corner((c & 1 ? b.max : b.min).x(), (c & 2 ? b.max : b.min).y(), (c & 4 ? b.max : b.min).z());
    const Vec3 p = T_camera_base * corner.cast<double>();
    if (p.z() <= 1e-3) { behind = true; break; }
    const double u = camera.fx * p.x() / p.z() + camera.cx, v = camera.fy * p.y() / p.z() + camera.cy;
    u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
  }
  int gu0 = 0, gu1 = gw, gv0 = 0, gv1 = gh;
  if (!behind) {
    gu0 = std::clamp(static_cast<int>(std::floor(u0 / stride)) - 1, 0, gw);
    gu1 = std::clamp(static_cast<int>(std::ceil(u1 / stride)) + 1, 0, gw);
    gv0 = std::clamp(static_cast<int>(std::floor(v0 / stride)) - 1, 0, gh);
    gv1 = std::clamp(static_cast<int>(std::ceil(v1 / stride)) + 1, 0, gh);
  }
  if (gu0 >= gu1 || gv0 >= gv1) return view;
  const Eigen::Matrix3d R = T_base_camera.linear();
  const Vec3 origin = T_base_camera.translation();
  std::vector<Vec3f> hit_points(view.z_depth.size()), hit_normals(view.z_depth.size());
  tbb::parallel_for(gv0, gv1, [&](int gv) {
    TraceRow(
        impl_->top, origin, max_range_m, gu0, gu1,
        [&](int gu, Vec3* dir) {
          const Vec3 ray_cam = camera.Ray(gu * stride, gv * stride);
          *dir = R * (ray_cam / ray_cam.norm());
          return true;
        },
        [&](int gu, const Vec3& dir, float distance, const Vec3& normal, unsigned instance) {
          if (instance == RTC_INVALID_GEOMETRY_ID) return;
          const std::size_t cell = static_cast<std::size_t>(gv) * gw + gu;
          // The hit's z depth: its distance along the unit ray, projected on the camera's axis.
          view.z_depth[cell] = static_cast<float>(distance * dir.dot(R.col(2)));
          // Embree gives an instance hit's normal in the link's own frame.
          Vec3 n = impl_->links[instance].T_base_link.linear() * normal.normalized();
          if (n.dot(dir) > 0) n = -n;  // facing the camera
          hit_points[cell] = (origin + distance * dir).cast<float>();
          hit_normals[cell] = n.cast<float>();
        });
  });
  for (std::size_t i = 0; i < view.z_depth.size(); ++i) {
    if (view.z_depth[i] <= 0) continue;
    view.points_base.points.push_back(hit_points[i]);
    view.points_base.normals.push_back(hit_normals[i]);
  }
  return view;
}

}  // namespace arref
