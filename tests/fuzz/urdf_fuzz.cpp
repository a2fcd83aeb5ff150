// libFuzzer target: a robot model from URDF text (core/robot: urdfdom, the kinematic tree,
// primitive and mesh geometry), then what the server does with a loaded robot: its actuated
// joints, completing a joint state, forward kinematics and the posed mesh. Mesh references
// resolve against a folder holding one small mesh of each format (mesh_fuzz covers the bytes).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include <console_bridge/console.h>
#include <spdlog/spdlog.h>

#include "arref/robot/robot_model.h"
#include "../temp_folder.h"

namespace {

namespace fs = std::filesystem;

// A tetrahedron as the three formats a URDF may name ("t.stl", "t.obj", "t.ply").
std::string MeshFolder() {
  static const arref::testing::TempFolder folder(fs::temp_directory_path().string(), "arref-fuzz-urdf-");
  if (folder.path().empty()) std::abort();  // nowhere to write the inputs
  const fs::path dir = folder.path();
  std::ofstream(dir / "t.obj") << "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  std::ofstream(dir / "t.ply") << "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                                  "property float z\nelement face 4\nproperty list uchar int vertex_indices\n"
                                  "end_header\n0 0 0\n0.1 0 0\n0 0.1 0\n0 0 0.1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
  std::ofstream(dir / "t.stl") << "solid t\nfacet normal 0 0 -1\nouter loop\nvertex 0 0 0\nvertex 0 0.1 0\n"
                                  "vertex 0.1 0 0\nendloop\nendfacet\nendsolid t\n";
  return dir.string();
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  spdlog::set_level(spdlog::level::off);
  console_bridge::setLogLevel(console_bridge::CONSOLE_BRIDGE_LOG_NONE);  // urdfdom's complaints
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::string dir = MeshFolder();
  const std::string urdf(reinterpret_cast<const char*>(data), size);
  auto model = arref::RobotModel::FromString(urdf, dir);
  if (!model.ok()) return 0;
  arref::JointValues given;
  double value = -3.0;
  for (const auto& joint : model->ActuatedJoints()) given[joint.name] = value += 0.7;
  auto joints = model->CompleteJoints(given);
  if (!joints.ok()) joints = model->CompleteJoints({});
  if (!joints.ok()) return 0;
  (void)model->LinkPoses(*joints);
  (void)model->PosedMesh(*joints);
  return 0;
}
