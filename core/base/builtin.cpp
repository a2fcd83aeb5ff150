#include "arref/base/builtin.h"

#include <cstdlib>
#include <filesystem>
#include <vector>

namespace arref {

Result<std::string> FindConfigFile(const std::string& relative) {
  std::vector<std::string> dirs;
  if (const char* env = std::getenv("ARREF_CONFIG_DIR")) dirs.emplace_back(env);
  dirs.emplace_back(ARREF_SOURCE_CONFIG_DIR);
  dirs.emplace_back(ARREF_INSTALL_CONFIG_DIR);
  std::string tried;
  for (const auto& dir : dirs) {
    const std::filesystem::path path = std::filesystem::path(dir) / relative;
    if (std::filesystem::is_regular_file(path)) return path.string();
    tried.append(" ").append(path.string());  // not " " + s: GCC 12 warns falsely (-Wrestrict, PR 105329)
  }
  return Status::NotFound("config file '" + relative + "' not found; looked at:" + tried);
}

Result<std::string> BuiltinRobotUrdf() { return FindConfigFile("robots/kr5_primitive.urdf"); }

}  // namespace arref
