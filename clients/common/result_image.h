// A picture of a registration result: the cropped scene mesh with the registered robot overlaid,
// seen from the robot's front and from above, side by side; the seed cube drawn as a wireframe;
// the scene coloured by its distance to the robot. Ray cast with core's Embree RayCaster and
// written as PNG by stb_image_write (Debian's libstb).
//
// Colours: robot orange (paler where the scene hides it); scene green within 1 cm of the robot,
// through blue at 5 cm to grey from 20 cm; seed cube and its forward axis magenta; background white.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/base/status.h"
#include "arref/fusion/raycaster.h"

namespace arref {

struct ResultImageOptions {
  int view_width = 640;  // each of the two views; the image is 2 * view_width wide
  int view_height = 480;
  double fov_deg = 50.0;         // horizontal
  double crop_radius_m = 2.0;    // scene kept round the seed, as the pipeline crops it
  double seed_cube_m = 0.2;      // edge of the drawn seed cube
};

// Everything in the internal (ROS) world frame.
struct ResultPicture {
  TriangleMesh scene_world;
  TriangleMesh robot_base;  // the posed robot in its base frame
  Iso3 T_world_base = Iso3::Identity();
  Iso3 T_world_seed = Iso3::Identity();
};

struct RgbImage {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> rgb;  // row-major, 3 bytes a pixel
};

// The two cameras (shared by the renderer and the tests that check where the robot lands).
struct ResultViews {
  PinholeCamera camera;
  Iso3 T_world_front = Iso3::Identity();  // optical frame, in front of the robot looking at it
  Iso3 T_world_top = Iso3::Identity();    // above it, looking down
};
ResultViews ResultViewsFor(const ResultPicture& picture, const ResultImageOptions& options);

// The side-by-side picture: front view in columns [0, view_width), top view after it.
Result<RgbImage> RenderResult(const ResultPicture& picture, const ResultImageOptions& options = {});

// PNG through stb_image_write; the error names the file.
Status WritePng(const RgbImage& image, const std::string& path);

// True for the robot's colours (opaque or seen through the scene), false for the scene's,
// the seed cube's and the background: r > g > b with a clear margin.
bool IsRobotColour(const std::uint8_t* rgb);

}  // namespace arref
