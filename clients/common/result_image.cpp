#include "result_image.h"

#include <stb/stb_image_write.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>

#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/sampling.h"
#include "arref/scene/spatial_mesh.h"

namespace arref {
namespace {

using Rgb = std::array<double, 3>;

constexpr Rgb kRobot{235, 125, 35};
constexpr Rgb kBackground{250, 250, 250};
constexpr Rgb kSeed{220, 0, 220};
// A scene hit this close behind the robot's surface is the headset's mesh of the robot itself
// (TSDF voxels of a few cm): the robot is drawn there.
constexpr double kRobotWinsWithinM = 0.04;
constexpr double kRobotMeshM = 0.08;  // a scene surface this near the robot is its mesh (one or two voxels)
constexpr std::size_t kRobotDistanceSamples = 20000;

Rgb Mix(const Rgb& a, const Rgb& b, double t) {
  t = std::clamp(t, 0.0, 1.0);
  return {a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t};
}

Rgb Shade(const Rgb& c, double incidence) {
  const double s = 0.35 + 0.65 * std::clamp(incidence, 0.0, 1.0);
  return {c[0] * s, c[1] * s, c[2] * s};
}

// Green on the robot, blue at 5 cm, grey from 20 cm.
Rgb DistanceColour(double d) {
  constexpr Rgb kOn{40, 175, 70}, kNear{50, 90, 220}, kFar{175, 175, 175};
  if (d <= 0.01) return kOn;
  if (d <= 0.05) return Mix(kOn, kNear, (d - 0.01) / 0.04);
  return Mix(kNear, kFar, (d - 0.05) / 0.15);
}

struct Box {
  Vec3 centre = Vec3::Zero();
  double radius = 0.3;  // half the diagonal, at least 0.3 m
  double top = 0.0;     // highest z
};

Box RobotBox(const TriangleMesh& robot_world) {
  Aabb box;
  for (const auto& v : robot_world.vertices) box.Extend(v);
  Box b;
  if (!box.valid()) return b;
  b.centre = (0.5f * (box.min + box.max)).cast<double>();
  b.radius = std::max(0.3, 0.5 * static_cast<double>((box.max - box.min).norm()));
  b.top = box.max.z();
  return b;
}

Vec3 HorizontalForward(const Iso3& T_world_base) {
  Vec3 f = T_world_base.linear() * Vec3::UnitX();
  f.z() = 0.0;
  return f.norm() > 1e-6 ? f.normalized() : Vec3::UnitX();
}

TriangleMesh Posed(const ResultPicture& p) {
  TriangleMesh robot = p.robot_base;
  robot.Transform(p.T_world_base);
  return robot;
}

void Put(RgbImage& image, int x, int y, const Rgb& c) {
  if (x < 0 || y < 0 || x >= image.width || y >= image.height) return;
  std::uint8_t* px = &image.rgb[(static_cast<std::size_t>(y) * image.width + x) * 3];
  for (int k = 0; k < 3; ++k) px[k] = static_cast<std::uint8_t>(std::clamp(c[k], 0.0, 255.0));
}

// A world-space segment drawn 2 px wide into the view whose columns start at x0.
void DrawSegment(RgbImage& image, int x0, const PinholeCamera& camera, const Iso3& T_world_camera, const Vec3& a,
                 const Vec3& b) {
  const Iso3 T_camera_world = T_world_camera.inverse();
  const Vec3 pa = T_camera_world * a, pb = T_camera_world * b;
  if (pa.z() <= 0.05 || pb.z() <= 0.05) return;  // behind the camera: not worth clipping
  const Eigen::Vector2d ua = camera.Project(pa), ub = camera.Project(pb);
  const int steps = std::max(1, static_cast<int>((ub - ua).norm()));
  for (int i = 0; i <= steps; ++i) {
    const Eigen::Vector2d u = ua + (ub - ua) * (static_cast<double>(i) / steps);
    for (int dy = 0; dy < 2; ++dy)
      for (int dx = 0; dx < 2; ++dx) {
        const int x = static_cast<int>(u.x()) + dx, y = static_cast<int>(u.y()) + dy;
        if (x >= 0 && x < camera.width) Put(image, x0 + x, y, kSeed);
      }
  }
}

void DrawSeed(RgbImage& image, int x0, const PinholeCamera& camera, const Iso3& T_world_camera, const Iso3& T_world_seed,
              double edge) {
  const double h = 0.5 * edge;
  std::array<Vec3, 8> c;
  for (int i = 0; i < 8; ++i) c[i] = T_world_seed * Vec3((i & 1) ? h : -h, (i & 2) ? h : -h, (i & 4) ? h : -h);
  for (int i = 0; i < 8; ++i)
    for (int bit : {1, 2, 4})
      if (!(i & bit)) DrawSegment(image, x0, camera, T_world_camera, c[i], c[i | bit]);
  // Its forward axis (toward the robot's front), as the hologram shows it.
  DrawSegment(image, x0, camera, T_world_camera, T_world_seed.translation(), T_world_seed * Vec3(3 * h, 0, 0));
}

struct ViewInputs {
  const RayCaster* scene = nullptr;  // null: nothing of the scene is left in this view
  const RayCaster& robot;
  const PointIndex& robot_points;
};

void RenderView(RgbImage& image, int x0, const PinholeCamera& camera, const Iso3& T_world_camera,
                const ViewInputs& in, double max_range) {
  std::vector<float> robot_incidence, scene_incidence;
  const RangeImage robot = in.robot.Render(camera, T_world_camera, max_range, &robot_incidence);
  RangeImage scene;
  if (in.scene) scene = in.scene->Render(camera, T_world_camera, max_range, &scene_incidence);
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * camera.width + u;
      const double rr = robot[i], sr = in.scene ? scene[i] : 0.0;
      Rgb colour = kBackground;
      double d = 1.0;  // the scene hit's distance to the robot
      if (sr > 0) {
        const Vec3 hit = T_world_camera * (camera.RayDirection(u, v) * sr);
        std::uint32_t nearest = 0;
        float sq = 0.0f;
        if (in.robot_points.NearestWithin(hit.cast<float>(), 0.25f * 0.25f, &nearest, &sq))
          d = std::sqrt(static_cast<double>(sq));
      }
      // The robot shows where it is nearer, and through the headset's own mesh of it, which the
      // TSDF lays a few centimetres outside the robot's surface.
      if (rr > 0 && (sr <= 0 || rr <= sr + kRobotWinsWithinM || d <= kRobotMeshM)) {
        colour = Shade(kRobot, robot_incidence[i]);
      } else if (sr > 0) {
        colour = Shade(DistanceColour(d), scene_incidence[i]);
        if (rr > 0) colour = Mix(colour, kRobot, 0.5);  // the robot seen through something else
      }
      Put(image, x0 + u, v, colour);
    }
}

}  // namespace

bool IsRobotColour(const std::uint8_t* rgb) {
  const int r = rgb[0], g = rgb[1], b = rgb[2];
  return r > g + 15 && g > b + 15 && r - b > 60;
}

ResultViews ResultViewsFor(const ResultPicture& picture, const ResultImageOptions& options) {
  const Box box = RobotBox(Posed(picture));
  ResultViews views;
  views.camera = PinholeCamera::FromFov(options.view_width, options.view_height, options.fov_deg);
  const double half_vertical = std::atan(0.5 * options.view_height / views.camera.focal_px);
  // The robot's bounding sphere fills about 80 % of the height, leaving room for what stands by it.
  const double distance = 1.25 * box.radius / std::tan(half_vertical);
  const Vec3 forward = HorizontalForward(picture.T_world_base);
  views.T_world_front = LookAt(box.centre + forward * distance + Vec3::UnitZ() * (0.5 * box.radius), box.centre);
  views.T_world_top = LookAt(box.centre + Vec3::UnitZ() * distance, box.centre);
  return views;
}

Result<RgbImage> RenderResult(const ResultPicture& picture, const ResultImageOptions& options) {
  if (options.view_width < 16 || options.view_height < 16)
    return Status::InvalidArgument("result image: views must be at least 16 x 16 pixels");
  const TriangleMesh robot_world = Posed(picture);
  if (robot_world.empty()) return Status::InvalidArgument("result image: the robot has no geometry");
  const Box box = RobotBox(robot_world);
  const ResultViews views = ResultViewsFor(picture, options);
  ARREF_ASSIGN_OR_RETURN(const RayCaster robot, RayCaster::Create(robot_world));
  const PointIndex robot_points(SampleSurface(robot_world, kRobotDistanceSamples, 1).points);

  // Cut away what would hide the robot: in front of it for the front view, above it for the top.
  const TriangleMesh cropped =
      CropToSphere(picture.scene_world, picture.T_world_seed.translation(), options.crop_radius_m);
  const Vec3 forward = HorizontalForward(picture.T_world_base);
  const auto centroid = [&](const Triangle& t) {
    return ((cropped.vertices[t[0]] + cropped.vertices[t[1]] + cropped.vertices[t[2]]) / 3.0f).cast<double>();
  };
  const TriangleMesh behind =
      KeepTriangles(cropped, [&](const Triangle& t) { return (centroid(t) - box.centre).dot(forward) < box.radius; });
  const TriangleMesh below = KeepTriangles(cropped, [&](const Triangle& t) { return centroid(t).z() < box.top + 0.1; });
  std::optional<RayCaster> scene_front, scene_top;
  if (!behind.empty()) {
    ARREF_ASSIGN_OR_RETURN(scene_front, RayCaster::Create(behind));
  }
  if (!below.empty()) {
    ARREF_ASSIGN_OR_RETURN(scene_top, RayCaster::Create(below));
  }

  RgbImage image;
  image.width = 2 * options.view_width;
  image.height = options.view_height;
  image.rgb.assign(static_cast<std::size_t>(image.width) * image.height * 3, 0);
  const double max_range = (views.T_world_top.translation() - box.centre).norm() + 2.0 * options.crop_radius_m;
  RenderView(image, 0, views.camera, views.T_world_front,
             ViewInputs{scene_front ? &*scene_front : nullptr, robot, robot_points}, max_range);
  RenderView(image, options.view_width, views.camera, views.T_world_top,
             ViewInputs{scene_top ? &*scene_top : nullptr, robot, robot_points}, max_range);
  DrawSeed(image, 0, views.camera, views.T_world_front, picture.T_world_seed, options.seed_cube_m);
  DrawSeed(image, options.view_width, views.camera, views.T_world_top, picture.T_world_seed, options.seed_cube_m);
  for (int v = 0; v < image.height; ++v) Put(image, options.view_width, v, {90, 90, 90});  // the views' border
  return image;
}

Status WritePng(const RgbImage& image, const std::string& path) {
  if (image.rgb.size() != static_cast<std::size_t>(image.width) * image.height * 3)
    return Status::InvalidArgument("PNG " + path + ": image buffer does not match its size");
  if (!stbi_write_png(path.c_str(), image.width, image.height, 3, image.rgb.data(), image.width * 3))
    return Status::IoError("PNG " + path + ": cannot write the file");
  return Status::Ok();
}

}  // namespace arref
