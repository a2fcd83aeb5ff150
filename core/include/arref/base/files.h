// Reading a whole file: a URDF, a server config, a mesh.
#pragma once

#include <optional>
#include <string>

namespace arref {

// The file's bytes, or nothing when it cannot be opened or read (callers name the file in their
// own error: a missing URDF and a missing config are different mistakes).
std::optional<std::string> ReadWholeFile(const std::string& path);

}  // namespace arref
