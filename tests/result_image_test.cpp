// Pictures of a result (clients/common/result_image.h) on a simulated cell with ground truth,
// read back through stb_image; and `arref register --image --export-robot` end to end.
#include <gtest/gtest.h>
#include <stb/stb_image.h>

#include <filesystem>
#include <memory>

#include "arref/base/frames.h"
#include "arref/fusion/raycaster.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/sampling.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/sim/cell_simulator.h"
#include "result_image.h"
#include "test_support.h"

namespace arref {
namespace {

struct Png {
  int width = 0, height = 0;
  std::unique_ptr<std::uint8_t, void (*)(void*)> pixels{nullptr, stbi_image_free};
  const std::uint8_t* at(int x, int y) const { return pixels.get() + (static_cast<std::size_t>(y) * width + x) * 3; }
};

Png ReadPng(const std::string& path) {
  Png png;
  int channels = 0;
  png.pixels.reset(stbi_load(path.c_str(), &png.width, &png.height, &channels, 3));
  return png;
}

bool IsMagenta(const std::uint8_t* px) { return px[0] > 180 && px[1] < 60 && px[2] > 180; }

struct Scene {
  ResultPicture picture;
  TriangleMesh robot_world;
};

Result<Scene> SimulatedScene() {
  ARREF_ASSIGN_OR_RETURN(const RobotModel robot, RobotModel::Load(testing::BuiltinRobotUrdf()));
  sim::SimOptions options = sim::SmallPreset();
  options.cell.joints = {{"joint_a2", -1.2}, {"joint_a3", 1.0}};
  // Nothing stands between the cameras and the robot: every robot pixel shows the robot (with
  // a table or boxes in front, those pixels rightly show the robot through them, paler).
  options.cell.table = false;
  options.cell.clutter_boxes = 0;
  options.seed_count = 1;
  ARREF_ASSIGN_OR_RETURN(const sim::SimulatedCell cell, sim::SimulateCell(robot, options, 4));
  SpatialMesh map;
  for (const Surface& s : cell.surfaces) ARREF_RETURN_IF_ERROR(map.Upsert(s));
  Scene scene;
  ARREF_ASSIGN_OR_RETURN(scene.picture.robot_base, robot.PosedMesh(cell.joints));
  scene.picture.scene_world = *map.MergedWorld();
  scene.picture.T_world_base = cell.T_world_base;
  scene.picture.T_world_seed = cell.seeds.at(0);
  scene.robot_world = scene.picture.robot_base;
  scene.robot_world.Transform(cell.T_world_base);
  return scene;
}

// The robot's visible surface points in a view: sampled points whose own pixel's ray hits the
// robot at the point's distance (so not hidden by another link).
std::vector<std::pair<int, int>> VisibleRobotPixels(const TriangleMesh& robot_world, const PinholeCamera& camera,
                                                    const Iso3& T_world_camera) {
  auto caster = RayCaster::Create(robot_world);
  EXPECT_TRUE(caster.ok());
  const RangeImage range = caster->Render(camera, T_world_camera, 100.0);
  std::vector<std::pair<int, int>> pixels;
  for (const Vec3f& p : SampleSurface(robot_world, 3000, 3).points) {
    const Vec3 c = T_world_camera.inverse() * p.cast<double>();
    const int i = camera.PixelOf(c);
    if (i >= 0 && std::abs(range[i] - c.norm()) < 0.01) pixels.emplace_back(i % camera.width, i / camera.width);
  }
  return pixels;
}

TEST(ResultImage, RobotLandsWhereItProjectsAndTheSceneIsNotRobotColoured) {
  ASSERT_OK_AND_ASSIGN(const Scene s, SimulatedScene());
  const ResultImageOptions options;
  ASSERT_OK_AND_ASSIGN(const RgbImage image, RenderResult(s.picture, options));
  const testing::ScopedTempDir tmp;
  const std::string path = tmp.path() + "/result.png";
  ASSERT_TRUE(WritePng(image, path).ok());
  const Png png = ReadPng(path);
  ASSERT_TRUE(png.pixels) << stbi_failure_reason();
  EXPECT_EQ(png.width, 2 * options.view_width);
  EXPECT_EQ(png.height, options.view_height);

  const ResultViews views = ResultViewsFor(s.picture, options);
  const std::pair<Iso3, int> panels[] = {{views.T_world_front, 0}, {views.T_world_top, options.view_width}};
  for (const auto& [T_world_camera, x0] : panels) {
    const auto visible = VisibleRobotPixels(s.robot_world, views.camera, T_world_camera);
    ASSERT_GT(visible.size(), 300u) << "the robot should fill a good part of each view";
    int robot_coloured = 0, under_seed = 0;
    for (const auto& [u, v] : visible) {
      const std::uint8_t* px = png.at(x0 + u, v);
      robot_coloured += IsRobotColour(px);
      under_seed += IsMagenta(px);  // the seed cube is drawn over everything
    }
    EXPECT_GT(robot_coloured, 0.9 * (visible.size() - under_seed)) << "panel at x " << x0;

    // Wherever the robot's rays miss it, nothing is robot-coloured; the scene round it is there,
    // coloured by distance (green on the robot's mesh, grey far from it).
    auto caster = RayCaster::Create(s.robot_world);
    ASSERT_TRUE(caster.ok());
    const RangeImage robot_range = caster->Render(views.camera, T_world_camera, 100.0);
    int wrong = 0, green = 0, grey = 0;
    for (int v = 0; v < views.camera.height; ++v)
      for (int u = 0; u < views.camera.width; ++u) {
        const std::uint8_t* px = png.at(x0 + u, v);
        if (robot_range[v * views.camera.width + u] > 0) continue;
        wrong += IsRobotColour(px);
        green += px[1] > px[0] + 40 && px[1] > px[2] + 30;
        grey += std::abs(px[0] - px[1]) < 6 && std::abs(px[1] - px[2]) < 6 && px[0] < 200;
      }
    EXPECT_EQ(wrong, 0) << "panel at x " << x0;
    EXPECT_GT(green, 100) << "panel at x " << x0;
    EXPECT_GT(grey, 1000) << "panel at x " << x0;
  }

  // The seed cube is drawn (magenta) in both panels.
  int magenta_front = 0, magenta_top = 0;
  for (int v = 0; v < png.height; ++v)
    for (int x = 0; x < png.width; ++x) {
      const std::uint8_t* px = png.at(x, v);
      (x < options.view_width ? magenta_front : magenta_top) += IsMagenta(px);
    }
  EXPECT_GT(magenta_front, 20);
  EXPECT_GT(magenta_top, 20);
}

TEST(ResultImage, BadInputIsRefused) {
  ResultPicture empty;
  EXPECT_EQ(RenderResult(empty).status().code(), StatusCode::kInvalidArgument);
  RgbImage wrong{.width = 4, .height = 4, .rgb = std::vector<std::uint8_t>(5)};
  EXPECT_EQ(WritePng(wrong, "/tmp/never.png").code(), StatusCode::kInvalidArgument);
  RgbImage fine{.width = 1, .height = 1, .rgb = std::vector<std::uint8_t>(3)};
  EXPECT_EQ(WritePng(fine, "/no/such/folder/x.png").code(), StatusCode::kIoError);
}

TEST(ResultImage, RegisterWritesTheImageAndThePosedRobot) {
  const testing::ScopedTempDir tmp;
  const std::string arref = std::string(ARREF_BINARY_DIR) + "/clients/cli/arref";
  const std::string base = tmp.path() + "/cell";
  auto r = testing::RunCommand(arref + " simulate --rng-seed 5 --frame unity --mesh-out " + base + ".ply --truth-out " +
                               base + ".json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = testing::RunCommand(arref + " register --frame unity --method arref-icp-fast --scene " + base + ".ply --truth " +
                          base + ".json --image " + base + ".png --export-robot " + base + "_robot.stl --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  int w = 0, h = 0, channels = 0;
  ASSERT_TRUE(stbi_info((base + ".png").c_str(), &w, &h, &channels)) << stbi_failure_reason();
  EXPECT_EQ(w, 1280);
  EXPECT_EQ(h, 480);

  // The exported robot is in the scene file's (Unity) frame, at the registered pose: back in
  // the internal frame it lies on the headset's mesh of the robot.
  ASSERT_OK_AND_ASSIGN(TriangleMesh robot, LoadMeshFile(base + "_robot.stl"));
  ASSERT_OK_AND_ASSIGN(TriangleMesh scene, LoadMeshFile(base + ".ply"));
  MeshToRos(robot, FrameConvention::kUnity);
  MeshToRos(scene, FrameConvention::kUnity);
  const PointCloud scene_points = SampleSurface(scene, 200000, 1);
  const PointIndex index(scene_points.points);
  int near = 0;
  const auto samples = SampleSurface(robot, 1000, 2).points;
  for (const Vec3f& p : samples) near += index.AnyWithin(p, 0.05f * 0.05f);
  EXPECT_GT(near, 0.5 * samples.size()) << "the posed robot should lie on the scene's robot";
}

}  // namespace
}  // namespace arref
