// Mesh files (assimp) and URDF mesh URI resolution.
#include <fmt/format.h>
#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <cstdlib>
#include <cctype>
#include <filesystem>
#include <sstream>
#include <string>

#include "arref/base/files.h"
#include "arref/robot/robot_model.h"
#include "ply_check.h"

namespace fs = std::filesystem;

namespace arref {
namespace {

constexpr std::string_view kPackageScheme = "package://";
constexpr std::string_view kFileScheme = "file://";

std::vector<std::string> PackageSearchPath(const std::vector<std::string>& given) {
  std::vector<std::string> path = given;
  // ROS users already keep their packages on ROS_PACKAGE_PATH; honour it after explicit entries.
  if (const char* env = std::getenv("ROS_PACKAGE_PATH")) {
    std::stringstream ss(env);
    for (std::string entry; std::getline(ss, entry, ':');)
      if (!entry.empty()) path.push_back(entry);
  }
  return path;
}

Result<std::string> ResolvePackageUri(const std::string& uri, const std::vector<std::string>& package_path) {
  const std::string rest = uri.substr(kPackageScheme.size());
  const auto slash = rest.find('/');
  if (slash == std::string::npos || slash == 0)
    return Status::InvalidArgument("malformed package URI '" + uri + "' (expected package://PKG/path)");
  const std::string package = rest.substr(0, slash);
  const std::string relative = rest.substr(slash + 1);
  std::vector<std::string> tried;
  for (const auto& entry : PackageSearchPath(package_path)) {
    const fs::path root(entry);
    std::vector<fs::path> candidates;
    if (root.filename() == package || fs::path(entry + "/.").parent_path().filename() == package)
      candidates.push_back(root / relative);
    candidates.push_back(root / package / relative);
    for (const auto& candidate : candidates) {
      if (fs::is_regular_file(candidate)) return candidate.lexically_normal().string();
      tried.push_back(candidate.string());
    }
  }
  std::string message = "mesh '" + uri + "' not found: package '" + package + "' ";
  if (tried.empty()) return Status::NotFound(message + "with an empty package path (pass --package-path)");
  message += "looked in:";
  for (const auto& t : tried) message += " " + t;
  return Status::NotFound(message);
}

// Appends a node's meshes (and its children's) in the root's frame. Polygons are split into fans
// and points and lines dropped; a face that names a vertex the mesh does not have is an error
// (assimp's binary PLY reader misreads some valid files that way, see LoadMeshFile).
Status AppendNode(const aiScene& scene, const aiNode& node, const aiMatrix4x4& T_parent, TriangleMesh* out) {
  const aiMatrix4x4 T = T_parent * node.mTransformation;
  for (unsigned i = 0; i < node.mNumMeshes; ++i) {
    const aiMesh& mesh = *scene.mMeshes[node.mMeshes[i]];
    const auto offset = static_cast<std::uint32_t>(out->vertices.size());
    for (unsigned v = 0; v < mesh.mNumVertices; ++v) {
      const aiVector3D p = T * mesh.mVertices[v];
      out->vertices.emplace_back(p.x, p.y, p.z);
    }
    for (unsigned f = 0; f < mesh.mNumFaces; ++f) {
      const aiFace& face = mesh.mFaces[f];
      for (unsigned k = 0; k < face.mNumIndices; ++k)
        if (face.mIndices[k] >= mesh.mNumVertices)
          return Status::IoError(fmt::format("face {} names vertex {} of {}", f, face.mIndices[k], mesh.mNumVertices));
      for (unsigned k = 2; k < face.mNumIndices; ++k)  // points and lines carry no surface
        out->triangles.push_back({offset + face.mIndices[0], offset + face.mIndices[k - 1], offset + face.mIndices[k]});
    }
  }
  for (unsigned c = 0; c < node.mNumChildren; ++c)
    ARREF_RETURN_IF_ERROR(AppendNode(scene, *node.mChildren[c], T, out));
  return Status::Ok();
}

bool IsPly(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".ply";
}

}  // namespace

Result<std::string> ResolveMeshUri(const std::string& uri, const std::string& urdf_dir,
                                   const std::vector<std::string>& package_path) {
  if (uri.rfind(kPackageScheme, 0) == 0) return ResolvePackageUri(uri, package_path);
  fs::path path = uri.rfind(kFileScheme, 0) == 0 ? fs::path(uri.substr(kFileScheme.size())) : fs::path(uri);
  if (path.is_relative()) path = fs::path(urdf_dir) / path;
  if (fs::is_regular_file(path)) return path.lexically_normal().string();
  return Status::NotFound("mesh '" + uri + "' not found: looked at " + path.lexically_normal().string());
}

Result<TriangleMesh> LoadMeshFile(const std::string& path) {
  if (!fs::is_regular_file(path)) return Status::NotFound("mesh file not found: " + path);
  const bool ply = IsPly(path);
  std::optional<std::string> ply_bytes;  // a PLY file is read once, checked, then handed to assimp from memory
  if (ply) {
    ply_bytes = ReadWholeFile(path);
    if (!ply_bytes) return Status::IoError("cannot read mesh " + path);
    ARREF_RETURN_IF_ERROR(CheckPly(*ply_bytes).WithContext("mesh " + path));
  }
  Assimp::Importer importer;
  // ROS meshes keep their authored axes: URDF link frames already say which way is up, so
  // COLLADA's <up_axis> must not rotate the geometry (rviz does the same).
  importer.SetPropertyBool(AI_CONFIG_IMPORT_COLLADA_IGNORE_UP_DIRECTION, true);
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE, aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  // Assimp 5.2's binary PLY reader misreads some valid files (a few faces get wrong vertex
  // counts), and its post-processing then aborts or crashes on them. A headset mesh in PLY is
  // read without post-processing: faces are checked and split into triangles here.
  const unsigned steps =
      ply ? 0u : unsigned{aiProcess_Triangulate | aiProcess_JoinIdenticalVertices | aiProcess_SortByPType};
  const aiScene* scene = ply ? importer.ReadFileFromMemory(ply_bytes->data(), ply_bytes->size(), steps, "ply")
                            : importer.ReadFile(path, steps);
  if (scene == nullptr || scene->mRootNode == nullptr)
    return Status::IoError("cannot read mesh " + path + ": " + importer.GetErrorString());
  TriangleMesh mesh;
  if (Status st = AppendNode(*scene, *scene->mRootNode, aiMatrix4x4(), &mesh); !st.ok())
    return st.WithContext("mesh " + path + " is malformed");
  if (mesh.triangles.empty()) return Status::IoError("mesh " + path + " has no triangles");
  return mesh;
}

}  // namespace arref

namespace arref {
namespace {

// Assimp's exporter id for a file name, by extension.
Result<std::string> ExportFormat(const std::string& path) {
  const std::string ext = fs::path(path).extension().string();
  if (ext == ".ply") return std::string("ply");  // ASCII: assimp reads its own binary PLY back wrong at times
  if (ext == ".stl") return std::string("stlb");
  if (ext == ".obj") return std::string("obj");
  return Status::InvalidArgument("cannot write mesh '" + path + "': use a .ply, .stl or .obj file name");
}

}  // namespace

Status SaveMeshFile(const TriangleMesh& mesh, const std::string& path) {
  ARREF_ASSIGN_OR_RETURN(const auto format, ExportFormat(path));
  // aiScene's destructor frees everything below, so all parts are allocated with new.
  aiScene scene;
  scene.mRootNode = new aiNode();
  scene.mMaterials = new aiMaterial*[1]{new aiMaterial()};
  scene.mNumMaterials = 1;
  auto* out = new aiMesh();
  scene.mMeshes = new aiMesh*[1]{out};
  scene.mNumMeshes = 1;
  scene.mRootNode->mMeshes = new unsigned[1]{0};
  scene.mRootNode->mNumMeshes = 1;
  out->mPrimitiveTypes = aiPrimitiveType_TRIANGLE;
  out->mNumVertices = static_cast<unsigned>(mesh.vertices.size());
  out->mVertices = new aiVector3D[mesh.vertices.size()];
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i)
    out->mVertices[i] = aiVector3D(mesh.vertices[i].x(), mesh.vertices[i].y(), mesh.vertices[i].z());
  out->mNumFaces = static_cast<unsigned>(mesh.triangles.size());
  out->mFaces = new aiFace[mesh.triangles.size()];
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    out->mFaces[i].mNumIndices = 3;
    out->mFaces[i].mIndices = new unsigned[3]{mesh.triangles[i][0], mesh.triangles[i][1], mesh.triangles[i][2]};
  }
  Assimp::Exporter exporter;
  if (exporter.Export(&scene, format, path) != AI_SUCCESS)
    return Status::IoError("cannot write mesh " + path + ": " + exporter.GetErrorString());
  return Status::Ok();
}

}  // namespace arref
