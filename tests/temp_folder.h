// A folder of one's own under a parent (mkdtemp: unique even beside other processes and
// checkouts using the same parent), removed with what is in it when this goes. No GoogleTest
// here: the libFuzzer targets use it too (tests/fuzz), and test_support.h's ScopedTempDir wraps it.
#pragma once

#include <stdlib.h>

#include <filesystem>
#include <string>
#include <system_error>

namespace arref::testing {

class TempFolder {
 public:
  // path() is empty when the folder could not be made; the caller reports that its own way.
  TempFolder(const std::string& parent, const std::string& prefix) {
    std::string pattern = parent + "/" + prefix + "XXXXXX";
    if (mkdtemp(pattern.data()) != nullptr) path_ = pattern;
  }
  ~TempFolder() {
    std::error_code ignored;  // what was left in it may be anything; nothing to report to here
    if (!path_.empty()) std::filesystem::remove_all(path_, ignored);
  }
  TempFolder(const TempFolder&) = delete;
  TempFolder& operator=(const TempFolder&) = delete;

  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

}  // namespace arref::testing
