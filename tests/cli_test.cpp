// `arref` end to end: the real binary, simulated cells with ground truth, bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <regex>
#include <nlohmann/json.hpp>

#include "test_support.h"

namespace arref {
namespace {

using testing::RunCommand;

std::string Arref() { return std::string(ARREF_BINARY_DIR) + "/clients/cli/arref"; }

class CliTest : public ::testing::Test {
 protected:
  // Simulates a small-preset cell with the built-in robot; returns the truth path.
  std::string Simulate(int rng_seed, const std::string& extra = "") {
    const std::string base = dir_ + "/cell" + std::to_string(rng_seed);
    const auto r = RunCommand(Arref() + " simulate --rng-seed " + std::to_string(rng_seed) + " --mesh-out " + base +
                              ".ply --truth-out " + base + ".json " + extra);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    return base;
  }
  const testing::ScopedTempDir tmp_;  // each test's cells of its own (two tests use the same seeds)
  const std::string dir_ = tmp_.path();
};

TEST_F(CliTest, SimulateWritesMeshAndTruth) {
  const std::string base = Simulate(11, "--seeds 4");
  std::ifstream in(base + ".json");
  const auto truth = nlohmann::json::parse(in);
  EXPECT_EQ(truth["seeds"].size(), 4u);
  EXPECT_EQ(truth["T_world_base"].size(), 16u);
  EXPECT_EQ(truth["joints"].size(), 6u);
  EXPECT_GT(truth["triangles"].get<int>(), 1000);
  EXPECT_GT(std::filesystem::file_size(base + ".ply"), 10000u);
}

// With no seed the whole map is searched (arref-auto): the cell's one robot is found, listed as a
// candidate with its own error, and a method that needs a seed says so.
TEST_F(CliTest, RegisterWithNoSeedSearchesTheWholeMap) {
  const std::string base = Simulate(12, "--seeds 1");
  const auto r = RunCommand(Arref() + " register --whole-map --scene " + base + ".ply --truth " + base + ".json --json");
  ASSERT_TRUE(r.exit_code == 0 || r.exit_code == 1) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["method"], "arref-auto");
  ASSERT_GE(j["candidates"].size(), 1u);
  EXPECT_LT(j["add_m"].get<double>(), 0.02);
  EXPECT_LT(j["candidates"][0]["add_m"].get<double>(), 0.02);
  EXPECT_GT(j["candidates_tried"].get<int>(), 0);
  const auto seeded = RunCommand(Arref() + " register --whole-map --method pcl-icp --scene " + base + ".ply");
  EXPECT_EQ(seeded.exit_code, 3) << seeded.out;
  EXPECT_NE(seeded.err.find("method 'pcl-icp' needs one"), std::string::npos) << seeded.err;
}

// PCL ICP with the paper's parameters from user-like seeds. Thresholds from
// `scripts/measure-icp.sh 10 10` (100 runs): built-in robot median ADD 10.4 mm, 99 % within
// 20 mm; vendor KR5 median 23.1 mm, p95 29.0 mm (the unseen back of the robot pulls ICP off).
constexpr double kBuiltinMedianAddMax = 0.015;
constexpr double kVendorMedianAddMax = 0.035;

TEST_F(CliTest, RegisterRecoversThePoseFromUserLikeSeeds) {
  std::vector<double> adds;
  for (int cell : {1, 2, 3}) {
    const std::string base = Simulate(cell, "--seeds 4");
    for (int seed = 0; seed < 4; ++seed) {
      const auto r = RunCommand(Arref() + " register --method pcl-icp --scene " + base + ".ply --truth " + base +
                                ".json --seed-index " + std::to_string(seed) + " --json");
      ASSERT_TRUE(r.exit_code == 0 || r.exit_code == 1) << r.err;
      const auto j = nlohmann::json::parse(r.out);
      EXPECT_EQ(j["method"], "pcl-icp");
      if (r.exit_code == 1) {  // status FAILED: exit 1, and it must really be a wrong pose
        EXPECT_EQ(j["status"], "FAILED");
        EXPECT_GT(j["add_m"].get<double>(), 0.02);
      }
      EXPECT_EQ(j["rms_points"], "all");
      EXPECT_EQ(j["points"]["scene"].get<int>(), 16000);
      EXPECT_GT(j["iterations"].get<int>(), 0);
      EXPECT_TRUE(j["timings_ms"].contains("register"));
      adds.push_back(j["add_m"].get<double>());
    }
  }
  std::sort(adds.begin(), adds.end());
  const double median = adds[adds.size() / 2];
  const auto within_20mm = std::count_if(adds.begin(), adds.end(), [](double a) { return a <= 0.020; });
  ::testing::Test::RecordProperty("median_add_mm", std::to_string(median * 1e3));
  EXPECT_LT(median, kBuiltinMedianAddMax);
  EXPECT_GE(within_20mm, 10) << "of " << adds.size();
}

// On the exact scene geometry arref-icp has no excuse: any error left is the method's own.
// Measured: ADD 0.1 mm on the vendor KR5 (the fused headset mesh gives 7-11 mm).
TEST_F(CliTest, DefaultMethodIsExactOnExactGeometry) {
  const std::string base = Simulate(31, "--seeds 3 --truth-mesh-out " + dir_ + "/cell31_exact.ply");
  for (int seed = 0; seed < 3; ++seed) {
    const auto r = RunCommand(Arref() + " register --scene " + dir_ + "/cell31_exact.ply --truth " + base +
                              ".json --json --seed-index " + std::to_string(seed));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const auto j = nlohmann::json::parse(r.out);
    EXPECT_EQ(j["method"], "arref-icp");
    EXPECT_EQ(j["status"], "OK") << j.value("status_reason", "");
    EXPECT_EQ(j["rms_points"], "visible");
    EXPECT_LT(j["add_m"].get<double>(), 0.002);
    // The fused shell's fit lies 23-24 mm away but explains this scene far worse, so it adds
    // little to the expected error (12 mm when the two models counted alike); what is left is the
    // map's part, from the tracking error the headset is assumed to have.
    EXPECT_LT(j["expected_error_m"]["surface"].get<double>(), 0.003) << j["expected_error_m"].dump();
    EXPECT_LT(j["expected_error_m"]["total"].get<double>(), 0.006) << j["expected_error_m"].dump();
    // Exact geometry is explained by the exact surface, not by a fused shell.
    // (A base set on its support after the fit adds "rests-on-support" at the end.)
    const auto& stages = j["stages_run"];
    EXPECT_NE(std::find(stages.begin(), stages.end(), "fitted-exact-surface"), stages.end()) << stages.dump();
    EXPECT_EQ(std::find(stages.begin(), stages.end(), "fitted-expected-surface"), stages.end()) << stages.dump();
  }
}

// `arref demo` (the README's one-process demo): each seed's result with its own expected error
// beside the true one. Measured: expected 4.5 and 3.9 mm, ADD 4.2 and 4.4 mm.
TEST_F(CliTest, DemoPrintsEachResultsExpectedAndTrueError) {
  const auto r = RunCommand(Arref() + " demo --seeds 2");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::regex line(R"(expected error ([0-9.]+) mm \| true error: ADD ([0-9.]+) mm)");
  int seeds = 0;
  for (auto it = std::sregex_iterator(r.out.begin(), r.out.end(), line); it != std::sregex_iterator(); ++it, ++seeds) {
    const double expected_mm = std::stod((*it)[1]), add_mm = std::stod((*it)[2]);
    EXPECT_GT(expected_mm, 2.0);
    EXPECT_LT(expected_mm, 10.0);
    EXPECT_LT(add_mm, 2 * expected_mm);
  }
  EXPECT_EQ(seeds, 2) << r.out;
  EXPECT_NE(r.out.find("2 of 2 seeds within 10 mm"), std::string::npos) << r.out;
}

// On a fused headset mesh the default fits the robot as the headset would mesh it. Measured
// (built-in robot, these cells and seeds): ADD 2.2-5.7 mm, all OK; arref-icp-exact 2.6-7.7 mm.
TEST_F(CliTest, DefaultMethodFitsTheExpectedHeadsetSurface) {
  std::vector<double> adds;
  for (int cell : {41, 42}) {
    const std::string base = Simulate(cell, "--seeds 3");
    for (int seed = 0; seed < 3; ++seed) {
      const auto r = RunCommand(Arref() + " register --scene " + base + ".ply --truth " + base +
                                ".json --json --seed-index " + std::to_string(seed));
      ASSERT_EQ(r.exit_code, 0) << r.err;
      const auto j = nlohmann::json::parse(r.out);
      EXPECT_EQ(j["status"], "OK") << j.value("status_reason", "");
      const auto& stages = j["stages_run"];
      EXPECT_EQ(stages.front(), "expected-surface");
      EXPECT_NE(std::find(stages.begin(), stages.end(), "fitted-expected-surface"), stages.end()) << stages.dump();
      EXPECT_EQ(std::find(stages.begin(), stages.end(), "fitted-exact-surface"), stages.end()) << stages.dump();
      // The default cell has a table 0.2 m from the base: refitted among the mapped objects.
      EXPECT_NE(std::find(stages.begin(), stages.end(), "in-context"), stages.end()) << stages.dump();
      EXPECT_TRUE(j["method_steps_ms"].contains("context"));
      EXPECT_LT(j["add_m"].get<double>(), 0.015);
      adds.push_back(j["add_m"].get<double>());
      // The expected error: most of it the map's (the config's 4 mm and 0.3 degrees per view over
      // the chosen walk's eyes), then the surface model's (half the distance between the fits of
      // the predicted shell and the exact surface), a millimetre the fit's. Measured: total
      // 4.1-5.1 mm (map 3.7-3.8, surface 1.6-3.3, fit 0.9-1.0) against ADD 2.8-3.9 mm.
      const auto& e = j["expected_error_m"];
      EXPECT_GT(e["map"].get<double>(), e["fit"].get<double>());
      EXPECT_GT(e["surface"].get<double>(), 0.0);
      EXPECT_GT(e["fit"].get<double>(), 0.0);
      EXPECT_GT(e["total"].get<double>(), 0.002);
      EXPECT_LT(e["total"].get<double>(), 0.010);
    }
  }
  std::sort(adds.begin(), adds.end());
  EXPECT_LT(adds[adds.size() / 2], 0.010) << "median ADD";
  // --no-context and arref-icp-fast skip that refit.
  const std::string base = dir_ + "/cell41";
  for (const char* variant : {"--no-context", "--method arref-icp-fast"}) {
    const auto r = RunCommand(Arref() + " register --scene " + base + ".ply --truth " + base + ".json --json " + variant);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const auto stages = nlohmann::json::parse(r.out)["stages_run"];
    EXPECT_EQ(std::find(stages.begin(), stages.end(), "in-context"), stages.end()) << variant << stages.dump();
  }
}

// The status thresholds were calibrated on arref-icp's point-to-plane fits. arref-icp-point
// was not part of that calibration: it still fits, but never says OK (one of its fits, 21 mm
// off, passed the thresholds: docs/engine.md, "GICP and point-to-point").
TEST_F(CliTest, UncalibratedMethodIsNeverOk) {
  const std::string base = Simulate(42, "--seeds 3");
  for (int seed = 0; seed < 3; ++seed) {
    const auto r = RunCommand(Arref() + " register --method arref-icp-point --scene " + base + ".ply --truth " + base +
                              ".json --json --seed-index " + std::to_string(seed));
    ASSERT_TRUE(r.exit_code == 0 || r.exit_code == 1) << r.err;
    const auto j = nlohmann::json::parse(r.out);
    EXPECT_EQ(j["status"], "LOW_CONFIDENCE");
    EXPECT_NE(j.value("status_reason", "").find("not calibrated"), std::string::npos) << j.value("status_reason", "");
    EXPECT_LT(j["add_m"].get<double>(), 0.020);  // a fit, not a failure
  }
}

// The truth file of `arref simulate` carries the walker's head path, as an app would log it.
TEST_F(CliTest, HeadPathGivesTheRefitItsEyes) {
  const std::string base = Simulate(43, "--seeds 2 --base-yaw 120");  // the user mapped the robot's left-back side
  const auto truth = nlohmann::json::parse(std::ifstream(base + ".json"));
  ASSERT_EQ(truth["head_path"].size(), 24u);
  for (int seed = 0; seed < 2; ++seed) {
    const auto r = RunCommand(Arref() + " register --scene " + base + ".ply --truth " + base + ".json --head-path " +
                              base + ".json --json --seed-index " + std::to_string(seed));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const auto j = nlohmann::json::parse(r.out);
    EXPECT_EQ(j["status"], "OK") << j.value("status_reason", "");
    const auto& stages = j["stages_run"];
    EXPECT_NE(std::find(stages.begin(), stages.end(), "head-path"), stages.end()) << stages.dump();
    EXPECT_LT(j["add_m"].get<double>(), 0.010);
  }
  // A path nowhere near the robot is not used, and says so.
  nlohmann::json far = {{"frame", "ros"}, {"head_path", {{100, 0, 1.6}, {100, 1, 1.6}, {100, 2, 1.6}}}};
  std::ofstream(base + "-far.json") << far.dump();
  auto r = RunCommand(Arref() + " register --scene " + base + ".ply --truth " + base + ".json --head-path " + base +
                      "-far.json --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto stages = nlohmann::json::parse(r.out)["stages_run"];
  EXPECT_NE(std::find(stages.begin(), stages.end(), "head-path-unused"), stages.end()) << stages.dump();
  EXPECT_NE(r.err.find("fewer than 3 positions"), std::string::npos) << r.err;
  // Bad files name the problem.
  std::ofstream(base + "-bad.json") << R"({"head_path": [[1, 2, 3], [1, "x", 3]]})";
  for (const auto& [file, text] : std::vector<std::pair<std::string, std::string>>{
           {base + "-bad.json", "position 1 is not [x,y,z]"}, {base + ".ply", "--head-path"}, {base + "-none.json", "cannot open"}}) {
    r = RunCommand(Arref() + " register --scene " + base + ".ply --truth " + base + ".json --head-path " + file);
    EXPECT_EQ(r.exit_code, 3) << file << "\n" << r.err;
    EXPECT_NE(r.err.find(text), std::string::npos) << file << "\n" << r.err;
  }
}

TEST_F(CliTest, UnityFrameRoundTrip) {
  // The same scene written in Unity convention registers to the same internal pose.
  const std::string ros = Simulate(5, "--seeds 1");
  const std::string unity = dir_ + "/cell5u";
  ASSERT_EQ(RunCommand(Arref() + " simulate --rng-seed 5 --seeds 1 --frame unity --mesh-out " + unity +
                       ".ply --truth-out " + unity + ".json").exit_code, 0);
  const auto a = RunCommand(Arref() + " register --scene " + ros + ".ply --truth " + ros + ".json --json");
  const auto b = RunCommand(Arref() + " register --frame unity --scene " + unity + ".ply --truth " + unity + ".json --json");
  ASSERT_EQ(a.exit_code, 0) << a.err;
  ASSERT_EQ(b.exit_code, 0) << b.err;
  const auto ja = nlohmann::json::parse(a.out), jb = nlohmann::json::parse(b.out);
  EXPECT_EQ(jb["frame"], "unity");
  EXPECT_NEAR(ja["add_m"].get<double>(), jb["add_m"].get<double>(), 0.002);
  for (int i = 0; i < 16; ++i)
    EXPECT_NEAR(ja["T_world_base"][i].get<double>(), jb["T_world_base"][i].get<double>(), 2e-3);
  // Unity position is (-y, z, x) of the internal one.
  EXPECT_NEAR(jb["position"][0].get<double>(), -ja["position"][1].get<double>(), 2e-3);
  EXPECT_NEAR(jb["position"][1].get<double>(), ja["position"][2].get<double>(), 2e-3);
  EXPECT_NEAR(jb["position"][2].get<double>(), ja["position"][0].get<double>(), 2e-3);
}

TEST_F(CliTest, BadInputGivesClearErrorsAndExitCodes) {
  const std::string base = Simulate(21, "--seeds 1");
  const std::string bad_joints = base + "-bad-joints.json";  // the truth, with a joint that is no number
  {
    std::ifstream in(base + ".json");
    auto truth = nlohmann::json::parse(in);
    truth["joints"]["joint_a2"] = "straight";
    std::ofstream(bad_joints) << truth.dump();
  }
  std::ofstream(base + "-array.json") << "[1, 2]";
  struct Case { std::string args; int code; std::string text; };
  const std::vector<Case> cases = {
      {"register --scene /nonexistent.ply --seed 0,0,0,0,0,0,1", 3, "/nonexistent.ply"},
      {"register --scene " + base + ".ply --seed 0,0,0", 3, "expected 7"},
      {"register --scene " + base + ".ply --seed 0,0,0,0,0,0,2", 3, "unit length"},
      {"register --scene " + base + ".ply --seed 0,0,x,0,0,0,1", 3, "'x' is not a number"},
      {"register --scene " + base + ".ply --truth " + base + ".json --method teleport", 3, "teleport"},
      {"register --scene " + base + ".ply --truth " + base + ".json --joints joint_z=1", 3, "joint_z"},
      {"register --scene " + base + ".ply --truth " + base + ".json --seed-index 9", 3, "1 seeds"},
      {"register --scene " + base + ".ply --truth " + bad_joints, 3, "joint 'joint_a2' is not a finite number"},
      {"register --scene " + base + ".ply --truth " + base + "-array.json", 3, "is not a JSON object"},
      {"register --scene " + base + ".ply --truth " + base + ".json --head-path " + base + "-array.json", 3,
       "is not a JSON object"},
      {"register --scene " + base + ".ply --seed 500,500,0,0,0,0,1", 4, "no scene triangles"},
      {"register --scene " + base + ".ply --truth " + base + ".json --robot /nope.urdf", 3, "/nope.urdf"},
      {"register --scene " + base + ".json --seed 0,0,0,0,0,0,1", 3, "cannot read mesh"},
      {"register --seed 0,0,0,0,0,0,1", 2, "--scene"},
      {"register --scene " + base + ".ply --frame enu --seed 0,0,0,0,0,0,1", 2, "enu"},
      {"bench --out " + base + "-bench --pose-jitter 0.5", 2, "--pose-jitter"},
      {"fly", 2, "subcommand"},
  };
  for (const auto& c : cases) {
    const auto r = RunCommand(Arref() + " " + c.args);
    EXPECT_EQ(r.exit_code, c.code) << c.args << "\n" << r.err;
    EXPECT_NE((r.err + r.out).find(c.text), std::string::npos) << c.args << "\n" << r.err;
  }
}

TEST_F(CliTest, RegistersTheVendorKr5) {
  ARREF_REQUIRE_SHARED();
  const std::string robot = "--robot " + testing::Kr5PackageDir() + "/urdf/kr5_arc.urdf --package-path " +
                            testing::SharedDir() + "/robots";
  const std::string base = dir_ + "/vendor";
  ASSERT_EQ(RunCommand(Arref() + " simulate " + robot + " --seeds 3 --joints joint_a2=-0.6,joint_a3=0.9 --mesh-out " +
                       base + ".ply --truth-out " + base + ".json").exit_code, 0);
  std::vector<double> adds;
  for (int seed = 0; seed < 3; ++seed) {
    const auto r = RunCommand(Arref() + " register --method pcl-icp " + robot + " --scene " + base + ".ply --truth " +
                              base + ".json --json --seed-index " + std::to_string(seed));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    adds.push_back(nlohmann::json::parse(r.out)["add_m"].get<double>());
  }
  std::sort(adds.begin(), adds.end());
  EXPECT_LT(adds[1], kVendorMedianAddMax) << "median ADD on the vendor KR5";
}

}  // namespace
}  // namespace arref
