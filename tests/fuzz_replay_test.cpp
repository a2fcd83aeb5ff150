// Replays one fuzz target (tests/fuzz/<target>_fuzz.cpp, linked in) over its seed corpus and
// over every crash reproducer kept in tests/fuzz/regressions/<target>/, so that the inputs
// that once crashed stay fixed in the normal and sanitizer suites, which have no libFuzzer.
// A target aborts on a broken invariant, so a failing input ends this test with a crash.
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);
extern "C" __attribute__((weak)) int LLVMFuzzerInitialize(int* argc, char*** argv);

namespace {

namespace fs = std::filesystem;

int ReplayFolder(const fs::path& dir) {
  int replayed = 0;
  if (!fs::is_directory(dir)) return 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (!entry.is_regular_file()) continue;
    std::ifstream in(entry.path(), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    SCOPED_TRACE(entry.path().string());
    EXPECT_EQ(LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size()), 0);
    ++replayed;
  }
  return replayed;
}

TEST(FuzzReplay, ARREF_FUZZ_TEST) {
  if (LLVMFuzzerInitialize) {
    int argc = 0;
    char** argv = nullptr;
    LLVMFuzzerInitialize(&argc, &argv);
  }
  const fs::path fuzz = fs::path(ARREF_SOURCE_DIR) / "tests" / "fuzz";
  const int seeds = ReplayFolder(fuzz / "corpus" / ARREF_FUZZ_TARGET);
  ReplayFolder(fuzz / "regressions" / ARREF_FUZZ_TARGET);
  EXPECT_GT(seeds, 0) << "no seeds in tests/fuzz/corpus/" << ARREF_FUZZ_TARGET;
}

}  // namespace
