// `arref demo`: simulate a KR5-like cell, register from user-like seeds, print the error.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>

#include "arref/base/stats.h"
#include "arref/scene/metrics.h"
#include "arref/pipeline/pipeline.h"
#include "arref/sim/cell_simulator.h"
#include "arref/scene/spatial_mesh.h"
#include "cli_common.h"
#include "commands.h"

namespace arref::cli {
namespace {

struct DemoArgs {
  RobotArgs robot;
  std::uint64_t rng_seed = 7;
  int seeds = 5;
};

void PrintPose(const char* label, const Iso3& T) {
  const Vec3 p = T.translation();
  const double yaw = YawOf(T) * 180 / M_PI;
  std::printf("%-14s x %+.4f  y %+.4f  z %+.4f m   yaw %+8.3f deg\n", label, p.x(), p.y(), p.z(), yaw);
}

int Run(const DemoArgs& args) {
  auto robot = LoadRobot(args.robot);
  if (!robot.ok()) return Fail(robot.status());
  auto joints = ParseJoints(args.robot.joints);
  if (!joints.ok()) return Fail(joints.status());
  sim::SimOptions sim_options = sim::SmallPreset();
  sim_options.cell.joints = *joints;
  sim_options.seed_count = args.seeds;
  spdlog::info("simulating a cell around robot '{}' (rng seed {})", robot->name(), args.rng_seed);
  auto cell = sim::SimulateCell(*robot, sim_options, args.rng_seed);
  if (!cell.ok()) return Fail(cell.status());
  SpatialMesh map;
  for (auto& s : cell->surfaces)
    if (auto st = map.Upsert(s); !st.ok()) return Fail(st);
  const TriangleMesh scene = *map.MergedWorld();
  RegistrationOptions options;
  auto model = RobotSide::Create(*robot, cell->joints, options.model_samples, options.sample_seed);
  if (!model.ok()) return Fail(model.status());
  std::printf("cell: %zu surfaces, %zu triangles, voxel %.3f m\n", map.size(), scene.triangles.size(), cell->voxel_m);
  PrintPose("true base", cell->T_world_base);

  std::vector<double> adds;
  for (std::size_t i = 0; i < cell->seeds.size(); ++i) {
    auto report = RegisterScene(**model, scene, cell->seeds[i], options);
    if (!report.ok()) return Fail(report.status().WithContext("seed " + std::to_string(i)));
    const PoseError seed_error = ComparePoses(cell->seeds[i], cell->T_world_base, (*model)->samples().points);
    const PoseError e = ComparePoses(report->T_world_base, cell->T_world_base, (*model)->samples().points);
    std::printf("\nseed %zu (off by %.0f mm, %.1f deg):\n", i, seed_error.translation_m * 1e3, seed_error.rotation_deg);
    PrintPose("  seed", cell->seeds[i]);
    PrintPose("  registered", report->T_world_base);
    std::printf("  rms %.1f mm | expected error %.1f mm | true error: ADD %.1f mm, translation %.1f mm, rotation %.2f deg | %.0f ms\n",
                report->rms_m * 1e3, report->precision.expected_error_m * 1e3, e.add_m * 1e3, e.translation_m * 1e3,
                e.rotation_deg, report->total_ms());
    adds.push_back(e.add_m);
  }
  if (adds.empty()) return kExitOk;
  const auto within = std::count_if(adds.begin(), adds.end(), [](double a) { return a <= 0.010; });
  std::printf("\n%s with %s: median ADD %.1f mm, %ld of %zu seeds within 10 mm\n", robot->name().c_str(),
              MethodName(options.method), Median(adds) * 1e3, static_cast<long>(within), adds.size());
  return kExitOk;
}

}  // namespace

void AddDemoCommand(CLI::App& app, int* exit_code) {
  auto args = std::make_shared<DemoArgs>();
  CLI::App* cmd = app.add_subcommand("demo", "Simulate a cell, register from user-like seeds, print the true error");
  AddRobotOptions(*cmd, args->robot);
  cmd->add_option("--rng-seed", args->rng_seed, "Random seed of the simulated cell")->capture_default_str();
  cmd->add_option("--seeds", args->seeds, "Number of user-like seeds")->check(CLI::Range(1, 1000))->capture_default_str();
  cmd->callback([args, exit_code] { *exit_code = Run(*args); });
}

}  // namespace arref::cli
