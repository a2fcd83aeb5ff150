// libFuzzer target: mesh files (core/robot LoadMeshFile: assimp, then arref's own face
// checks) from arbitrary bytes. Byte 0 picks the format (STL, PLY or OBJ, as the file's
// extension says); the rest is the file, written to a private temporary folder because
// LoadMeshFile reads by path, exactly as a URDF's meshes are read.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "arref/robot/robot_model.h"
#include "../temp_folder.h"

namespace {

namespace fs = std::filesystem;

const std::string& Folder() {
  static const arref::testing::TempFolder folder(fs::temp_directory_path().string(), "arref-fuzz-mesh-");
  if (folder.path().empty()) std::abort();  // nowhere to write the inputs
  return folder.path();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  static const char* const kExtensions[] = {".stl", ".ply", ".obj"};
  const fs::path path = fs::path(Folder()) / (std::string("m") + kExtensions[data[0] % 3]);
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data + 1), static_cast<std::streamsize>(size - 1));
    if (!out) std::abort();
  }
  auto mesh = arref::LoadMeshFile(path.string());
  if (mesh.ok()) {
    // What every caller relies on: faces name existing vertices.
    for (const auto& t : mesh->triangles)
      for (int k = 0; k < 3; ++k)
        if (t[k] >= mesh->vertices.size()) std::abort();
  }
  return 0;
}
