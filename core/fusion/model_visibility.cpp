#include "arref/fusion/model_visibility.h"

#include <cmath>
#include <numbers>

#include "arref/fusion/raycaster.h"

namespace arref {

TriangleMesh WithFloor(const TriangleMesh& robot_base) {
  TriangleMesh scene = robot_base;
  const float r = 10.0f;
  const auto n = static_cast<std::uint32_t>(scene.vertices.size());
  const float z = FloorHeight(BoundsOf(robot_base.vertices));
  scene.vertices.insert(scene.vertices.end(), {{-r, -r, z}, {r, -r, z}, {r, r, z}, {-r, r, z}});
  scene.triangles.push_back({n, n + 1, n + 2});
  scene.triangles.push_back({n, n + 2, n + 3});
  return scene;
}

PointCloud VisiblePoints(const PointCloud& model) {
  if (!model.has_visibility()) return model;
  std::vector<std::uint32_t> keep;
  for (std::size_t i = 0; i < model.size(); ++i)
    if (model.visibility[i] > 0) keep.push_back(static_cast<std::uint32_t>(i));
  return keep.size() >= 50 ? model.Subset(keep) : model;
}

Result<std::vector<float>> ModelVisibility(const TriangleMesh& robot_base, const PointCloud& samples,
                                           const VisibilityOptions& options) {
  if (!samples.has_normals()) return Status::InvalidArgument("model visibility needs sample normals");
  if (options.azimuths <= 0 || options.distances_m.empty() || options.eye_heights_m.empty())
    return Status::InvalidArgument("model visibility needs at least one eye position");
  const Aabb box = BoundsOf(robot_base.vertices);
  auto caster = RayCaster::Create(options.floor ? WithFloor(robot_base) : robot_base);
  if (!caster.ok()) return caster.status().WithContext("model visibility");
  const PinholeCamera camera = PinholeCamera::FromFov(options.image_width, options.image_height,
                                                      options.fov_horizontal_deg);
  const Vec3 target = ((box.min + box.max) / 2).cast<double>();
  std::vector<int> seen(samples.size(), 0);
  int views = 0;
  for (int a = 0; a < options.azimuths; ++a) {
    const double azimuth = 2 * std::numbers::pi * a / options.azimuths;
    for (double distance : options.distances_m)
      for (double height : options.eye_heights_m) {
        const Vec3 eye(distance * std::cos(azimuth), distance * std::sin(azimuth), height);
        const Iso3 T_base_camera = LookAt(eye, target);
        const RangeImage range = caster->Render(camera, T_base_camera, 2 * (distance + box.max.norm()));
        const Iso3 T_camera_base = T_base_camera.inverse();
        ++views;
        for (std::size_t i = 0; i < samples.size(); ++i) {
          const Vec3 p = samples.points[i].cast<double>();
          if (samples.normals[i].cast<double>().dot(eye - p) <= 0) continue;  // facing away
          const Vec3 p_camera = T_camera_base * p;
          const int pixel = camera.PixelOf(p_camera);
          if (pixel >= 0 && range[pixel] > 0 && std::abs(range[pixel] - p_camera.norm()) < options.depth_tolerance_m)
            ++seen[i];
        }
      }
  }
  std::vector<float> fraction(samples.size());
  for (std::size_t i = 0; i < samples.size(); ++i) fraction[i] = static_cast<float>(seen[i]) / views;
  return fraction;
}

}  // namespace arref
