// Files that ship with arref: the built-in robot and default configuration.
#pragma once

#include <string>

#include "arref/base/status.h"

namespace arref {

// Finds config/RELATIVE in the source tree (development) or the install prefix
// (share/arref/config); ARREF_CONFIG_DIR overrides both.
Result<std::string> FindConfigFile(const std::string& relative);

// The built-in robot (KR5 arc kinematics with primitive links): config/robots/kr5_primitive.urdf.
Result<std::string> BuiltinRobotUrdf();

}  // namespace arref
