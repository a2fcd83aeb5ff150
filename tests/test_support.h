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

// ASSERT_OK_AND_ASSIGN(lhs, expr): expr is a Result<T>; fails the test (returning from it) with
// its Status when it holds none, else moves the value into lhs, which may declare a variable.
#define ARREF_TEST_CONCAT_INNER_(a, b) a##b
#define ARREF_TEST_CONCAT_(a, b) ARREF_TEST_CONCAT_INNER_(a, b)
#define ASSERT_OK_AND_ASSIGN(lhs, expr) ASSERT_OK_AND_ASSIGN_IMPL_(ARREF_TEST_CONCAT_(assert_result_, __LINE__), lhs, expr)
#define ASSERT_OK_AND_ASSIGN_IMPL_(result, lhs, expr)         \
  auto result = (expr);                                     \
  ASSERT_TRUE(result.ok()) << result.status().ToString();   \
  lhs = std::move(result).value()

// Tests on the vendor KR5 package need ../shared; CI has it, a user's fresh clone may not.
#define ARREF_REQUIRE_SHARED()                                                              \
  do {                                                                                      \
    if (!::arref::testing::HaveShared())                                                    \
      GTEST_SKIP() << "../shared/robots/kuka_kr5_support not found at "                     \
                   << ::arref::testing::SharedDir()                                         \
                   << ": the vendor KR5 package is only beside CI's and developers' clones"; \
  } while (0)

#include <array>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <sys/wait.h>
#include <unistd.h>

#include "temp_folder.h"

namespace arref::testing {

// A directory of the running test's own, removed with what is in it when this goes: CTest runs
// test cases in parallel processes (and other checkouts run theirs in the same temp dir), so a
// fixed path would be written by two at once.
class ScopedTempDir {
 public:
  ScopedTempDir() : folder_(::testing::TempDir(), "arref_" + TestName() + "_") {
    if (folder_.path().empty()) ADD_FAILURE() << "cannot create a directory in " << ::testing::TempDir();
  }
  const std::string& path() const { return folder_.path(); }

 private:
  static std::string TestName() {
    const ::testing::TestInfo* test = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = test ? std::string(test->test_suite_name()) + "." + test->name() : "test";
    for (char& c : name)
      if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.') c = '_';  // parameterised names have '/'
    return name;
  }
  TempFolder folder_;
};

struct CommandResult {
  int exit_code = -1;
  std::string out;  // stdout
  std::string err;  // stderr
};

// Runs a shell command line, capturing stdout and stderr.
inline CommandResult RunCommand(const std::string& command) {
  // Per process: CTest runs test cases in parallel processes.
  const std::string err_path = ::testing::TempDir() + "/arref_cmd_stderr_" + std::to_string(getpid()) + ".txt";
  CommandResult result;
  FILE* pipe = popen((command + " 2>" + err_path).c_str(), "r");
  if (pipe == nullptr) return result;
  std::array<char, 4096> buffer;
  for (std::size_t n; (n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0;) result.out.append(buffer.data(), n);
  const int status = pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  {
    std::ifstream err(err_path);
    std::stringstream ss;
    ss << err.rdbuf();
    result.err = ss.str();
  }
  std::remove(err_path.c_str());  // one per test process: left behind, they pile up in the temp dir
  return result;
}

}  // namespace arref::testing
