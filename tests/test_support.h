// Locations of test data: the repo's own config and ../shared (absent on a user's fresh clone).
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

namespace arref::testing {

inline std::string SourceDir() { return ARREF_SOURCE_DIR; }
inline std::string BuiltinRobotUrdf() { return SourceDir() + "/config/robots/kr5_primitive.urdf"; }
inline std::string SharedDir() { return ARREF_SHARED_DIR; }
inline std::string Kr5PackageDir() { return SharedDir() + "/robots/kuka_kr5_support"; }
inline bool HaveShared() { return std::filesystem::exists(Kr5PackageDir() + "/urdf/kr5_arc.urdf"); }

}  // namespace arref::testing

// Tests on the vendor KR5 package need ../shared; CI has it, a user's fresh clone may not.
#define ARREF_REQUIRE_SHARED()                                                              \
  do {                                                                                      \
    if (!::arref::testing::HaveShared())                                                    \
      GTEST_SKIP() << "../shared/robots/kuka_kr5_support not found at "                     \
                   << ::arref::testing::SharedDir()                                         \
                   << ": the vendor KR5 package is only beside CI's and developers' clones"; \
  } while (0)
