// Simulated cells, running registrations against ground truth, and per-row statistics.
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <fstream>
#include <numeric>

#include "arref/base/split_mix.h"
#include "arref/base/stats.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/robot/joint_motion.h"
#include "arref/scene/metrics.h"
#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/sampling.h"
#include "arref/scene/spatial_mesh.h"
#include "bench.h"
#include "result_image.h"

namespace arref::bench {
namespace {

Result<sim::SimOptions> OptionsFor(const std::string& kind, const std::string& size) {
  sim::SimOptions o = size == "big" ? sim::BigPreset() : sim::SmallPreset();
  if (kind == "near-table") o.cell.table_gap_m = 0.05;  // the paper's failure case for Super4PCS
  else if (kind == "clutter") o.cell.clutter_boxes = 12;
  else if (kind == "second-robot") o.cell.second_robot = true;
  else if (kind == "empty") o.cell.robot_present = false;  // seeds point where it would stand
  else if (kind != "default") return Status::InvalidArgument("unknown bench scene kind '" + kind + "'");
  return o;
}

// A varied but reproducible arm pose: every actuated joint within +-0.5 rad of zero.
JointValues RandomJoints(const RobotModel& robot, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  JointValues joints;
  for (const auto& j : robot.ActuatedJoints()) {
    double v = u(rng);
    if (j.has_limits) v = std::clamp(v, j.lower, j.upper);
    joints[j.name] = v;
  }
  return joints;
}

// Peak resident memory since the last reset, in MB (Linux: VmHWM; reset via clear_refs).
double PeakMb() {
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;
}
void ResetPeak() { std::ofstream("/proc/self/clear_refs") << "5"; }

void ExecuteOne(Job& job) {
  Run& run = job.run;
  const Cell& cell = *job.cell;
  const Iso3& truth = cell.sim.T_world_base;
  if (job.seed_only) {
    // The user's guess as the answer: RMS over the same crop and sample as a registration.
    const TriangleMesh cropped = CropToSphere(cell.scene_world, job.T_world_seed.translation(), job.options.crop_radius_m);
    const PointIndex index(SampleSurface(cropped, job.options.scene_samples, job.options.sample_seed).points);
    run.rms_m = MeasureFit(cell.robot->samples().points, job.T_world_seed, index, job.options.inlier_threshold_m).rms_m;
    const PoseError e = ComparePoses(job.T_world_seed, truth, cell.robot->samples().points);
    run.ok = true, run.add_m = e.add_m, run.translation_m = e.translation_m, run.rotation_deg = e.rotation_deg;
    run.vertical_m = e.vertical_m, run.horizontal_m = e.horizontal_m;
    return;
  }
  auto report = RegisterScene(*cell.robot, cell.scene_world, job.T_world_seed, job.options);
  if (!report.ok()) {
    run.error = report.status().ToString();
    return;
  }
  const PoseError e = ComparePoses(report->T_world_base, truth, cell.robot->samples().points);
  run.ok = true;
  run.status = ResultStatusName(report->status);
  run.rms_m = report->rms_m, run.add_m = e.add_m, run.translation_m = e.translation_m, run.rotation_deg = e.rotation_deg;
  run.vertical_m = e.vertical_m, run.horizontal_m = e.horizontal_m;
  if (cell.sim.T_world_base_mesh)
    run.method_error_m = ComparePoses(report->T_world_base, *cell.sim.T_world_base_mesh, cell.robot->samples().points).add_m;
  run.iterations = report->iterations;
  run.precision = report->precision;
  run.stages = fmt::format("{}", fmt::join(report->stages_run, ";"));
  for (const auto& t : report->timings) run.stage_ms[t.stage] += t.ms;
  for (const auto& t : report->method_steps) run.stage_ms["register/" + t.stage] += t.ms;
  run.total_ms = report->total_ms();
  if (!job.image_path.empty()) {
    const ResultPicture picture{.scene_world = cell.scene_world, .robot_base = cell.robot_base,
                                .T_world_base = report->T_world_base, .T_world_seed = job.T_world_seed};
    auto image = RenderResult(picture, ResultImageOptions{.crop_radius_m = job.options.crop_radius_m});
    const Status written = image.ok() ? WritePng(*image, job.image_path) : image.status();
    if (!written.ok()) spdlog::warn("bench: no picture of {}: {}", job.image_path, written.ToString());
  }
}

// A user's own walk: how far round, where, how far off, how tall, how many looks.
void VaryWalk(sim::ScanOptions* scan, std::mt19937_64& rng) {
  using U = std::uniform_real_distribution<double>;
  scan->path_arc_deg = std::clamp(scan->path_arc_deg + U(-40.0, 40.0)(rng), 30.0, 360.0);
  scan->path_center_deg = U(-30.0, 30.0)(rng);
  scan->path_radius_m = U(1.5, 2.4)(rng);
  scan->eye_height_m = U(1.5, 1.8)(rng);
  scan->views = std::uniform_int_distribution<int>(16, 32)(rng);
  scan->path_wander_m = 0.1;
}

}  // namespace

Result<std::vector<Cell>> MakeCells(const RobotModel& robot, const std::vector<std::string>& kinds, const std::string& size,
                                    int cells_per_kind, int seeds_per_cell, std::uint64_t rng_seed,
                                    const CellVariation& variation) {
  std::vector<Cell> cells;
  const RegistrationOptions defaults;
  for (const auto& kind : kinds) {
    for (int i = 0; i < cells_per_kind; ++i) {
      ARREF_ASSIGN_OR_RETURN(sim::SimOptions options, OptionsFor(kind, size));
      // One cell seed per (kind, index): the same cells at every size and in every experiment.
      const std::uint64_t seed = rng_seed * 1000 + static_cast<std::uint64_t>(i) * 17 +
                                 static_cast<std::uint64_t>(&kind - kinds.data()) * 101;
      std::mt19937_64 rng(seed);
      options.cell.joints = RandomJoints(robot, rng);
      options.seed_count = seeds_per_cell;
      options.seed_noise = variation.seed_noise;
      if (variation.walk_arc_deg > 0) options.scan.path_arc_deg = variation.walk_arc_deg;
      if (variation.pose_jitter_m >= 0) sim::SetPoseJitter(&options.scan, variation.pose_jitter_m);
      if (variation.walk_any_side) options.cell.base_yaw_deg = std::uniform_real_distribution<double>(-180.0, 180.0)(rng);
      if (variation.varied_walk) VaryWalk(&options.scan, rng);
      auto sim = sim::SimulateCell(robot, options, seed);
      if (!sim.ok()) return sim.status().WithContext("bench cell " + kind + " " + std::to_string(i));
      Cell cell{kind, size, i, std::move(*sim), {}, {}};
      SpatialMesh map;
      for (auto& s : cell.sim.surfaces) ARREF_RETURN_IF_ERROR(map.Upsert(s));
      cell.scene_world = *map.MergedWorld();
      ARREF_ASSIGN_OR_RETURN(cell.robot,
                             RobotSide::Create(robot, cell.sim.joints, defaults.model_samples, defaults.sample_seed));
      ARREF_ASSIGN_OR_RETURN(cell.robot_base, robot.PosedMesh(cell.sim.joints));
      spdlog::info("bench: {} cell '{}' #{}: {} triangles", size, kind, i, cell.scene_world.triangles.size());
      cells.push_back(std::move(cell));
    }
  }
  return cells;
}

namespace {

// The joints that swing while the cell is mapped (RobustnessConfig::motion), with an amplitude
// of 0.2-0.8 rad and 1-3 swings over the walk, drawn from a stream of the cell's own.
sim::MappingMotion DrawMotion(const RobotModel& robot, const std::string& motion, std::uint64_t seed) {
  sim::MappingMotion m;
  if (motion == "none") return m;
  const std::vector<JointInfo> joints = robot.ActuatedJoints();
  const std::size_t n = joints.size();
  const std::size_t first = motion == "wrist" ? n / 2 : motion == "arm" ? std::min<std::size_t>(1, n) : 0;
  for (std::size_t i = first; i < n; ++i) m.joints.push_back(joints[i].name);
  std::mt19937_64 rng(SplitMix64(seed ^ 0x4D4F5645u));
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  m.amplitude_rad = 0.2 + 0.6 * unit(rng);
  m.cycles = 1.0 + 2.0 * unit(rng);
  return m;
}

// A pedestal under half the cells, 0.2-0.7 m high (as the seedless rooms mount arms), from a
// stream of the cell's own so that the rest of the cell is drawn as without it. An arm that
// reaches below its base must stand on one that clears that reach by 5 cm, as a real cell's would.
Result<double> DrawPedestal(const RobotModel& robot, const JointValues& joints, std::uint64_t seed) {
  std::mt19937_64 rng(SplitMix64(seed ^ 0x50454445u));
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const bool mounted = unit(rng) < 0.5;
  const double drawn = 0.2 + 0.5 * unit(rng);
  ARREF_ASSIGN_OR_RETURN(const TriangleMesh posed, robot.PosedMesh(robot.ClampedToLimits(joints)));
  ARREF_ASSIGN_OR_RETURN(const double rest, RestingHeight(robot));
  const double reach_below = posed.empty() ? 0.0 : rest - BoundsOf(posed.vertices).min.z();
  double height = mounted ? drawn : 0.0;
  if (reach_below > 0) height = std::max(height, reach_below + 0.05);
  return height;
}

// The model side a fit on this cell rests on (RobustnessConfig::moving_fit), chosen from what
// a server knows: the joint ranges a stream sent while the user mapped, and the map's edges.
// Marks the cell's map as not showing the robot as posed when much of it moved (as the server).
Status SetCellRobotSide(const RobotModel& robot, const std::string& moving_fit, Cell* cell) {
  const RegistrationOptions defaults;
  std::optional<std::set<std::string>> links;
  const sim::SimulatedCell& sim = cell->sim;
  if (!sim.joints_while_mapping.empty()) {
    const double voxel = MedianEdgeLength(cell->scene_world);
    const bool always = moving_fit == "unmoved";
    ARREF_ASSIGN_OR_RETURN(const MovingFit fit,
                           ChooseMovingFit(robot, sim.joints, sim.joints_while_mapping, kJointMotionWhileMappingRad, voxel,
                                           always ? 0.0 : kMovingFitMinLeverageVoxels, always ? 0.0 : kMovingFitMinMovedShare));
    if (moving_fit != "whole") links = fit.links;
    if (fit.much_moved && moving_fit == "auto") cell->map_not_as_posed = "the joints moved while the map was made";
    spdlog::info("bench: {}: {} unmoved links, {:.0f} % of the model's surface, yaw leverage {:.3f} m = {:.1f} voxels "
                 "of {:.3f} m: the fit rests on {}", robot.name(), fit.unmoved.size(), 100 * fit.unmoved_area_share,
                 fit.yaw_leverage_m, fit.yaw_leverage_m / voxel, voxel, links ? "them" : "the whole model");
  }
  ARREF_ASSIGN_OR_RETURN(cell->robot, RobotSide::Create(robot, sim.joints, defaults.model_samples, defaults.sample_seed,
                                                        links ? &*links : nullptr));
  return Status::Ok();
}

// The own mesher's voxel for RobustnessConfig::own_voxels: uniform in 2-6 cm, the range of the
// Open3D device's, from a stream of the cell's own so that the rest of the cell is drawn as without it.
double DrawOwnVoxel(std::uint64_t seed) {
  std::mt19937_64 rng(SplitMix64(seed ^ 0x564F58u));
  return std::uniform_real_distribution<double>(0.02, 0.06)(rng);
}

}  // namespace

Result<Cell> MakeCell(const RobotModel& robot, const std::string& kind, int index, std::uint64_t seed, sim::Mesher mesher,
                      std::shared_ptr<const RobotSide> robot_side, const RobustnessConfig& rc) {
  auto options = OptionsFor(kind, "small");
  if (!options.ok()) return options.status();
  std::mt19937_64 rng(seed);
  options->cell.joints = RandomJoints(robot, rng);
  options->cell.motion = DrawMotion(robot, rc.motion, seed);
  if (rc.pedestals) {
    ARREF_ASSIGN_OR_RETURN(options->cell.pedestal_height_m, DrawPedestal(robot, options->cell.joints, seed));
  }
  options->seed_count = 0;  // the experiment draws its seeds by family
  options->fusion.mesher = mesher;
  if (rc.own_voxels && mesher == sim::Mesher::kOwn) options->fusion.voxel_m = DrawOwnVoxel(seed);
  ARREF_RETURN_IF_ERROR(sim::LeaveOutErrors(rc.without, seed, &*options));
  auto sim = sim::SimulateCell(robot, *options, seed);
  if (!sim.ok()) return sim.status().WithContext("bench cell " + kind + " " + std::to_string(index) + " of " + robot.name());
  Cell cell{kind, "small", index, std::move(*sim), {}, std::move(robot_side)};
  SpatialMesh map;
  for (auto& s : cell.sim.surfaces) ARREF_RETURN_IF_ERROR(map.Upsert(s));
  cell.scene_world = *map.MergedWorld();
  if (!cell.robot) ARREF_RETURN_IF_ERROR(SetCellRobotSide(robot, rc.moving_fit, &cell));
  spdlog::info("bench: {} cell '{}' #{} ({} mesher): {} triangles, voxel {:.3f} m, pedestal {:.2f} m", robot.name(), kind,
               index, sim::MesherName(mesher), cell.scene_world.triangles.size(), cell.sim.voxel_m,
               options->cell.pedestal_height_m);
  if (mesher == sim::Mesher::kOpen3d) {
    const sim::DeviceVariation& d = cell.sim.device;
    spdlog::info("bench:   device: voxel {:.3f} m, {:.0f} triangles/m^3, quantum {:.4f} m, {:.2f} m surfaces at {} times, "
                 "errors to {:.4f} m / {:.2f} deg, {} patches to {:.2f} m, noise {:.4f} m, walk {:.0f} deg at {:.2f} m",
                 d.voxel_m, d.triangles_per_m3, d.quantisation_m, d.surface_size_m, d.surface_updates, d.surface_error_max_m,
                 d.surface_error_max_deg, d.missing_patches, d.patch_radius_max_m, d.depth_noise_m, d.walk_arc_deg,
                 d.walk_distance_m);
  }
  return cell;
}

std::vector<Run> Execute(std::vector<Job>& jobs, int parallel_jobs) {
  std::atomic<std::size_t> done = 0;
  auto one = [&](std::size_t i) {
    if (parallel_jobs <= 1) ResetPeak();  // per-run peak only means something when runs do not overlap
    ExecuteOne(jobs[i]);
    jobs[i].run.peak_mb = PeakMb();
    if (const std::size_t n = ++done; n % 50 == 0) spdlog::info("bench: {} of {} runs", n, jobs.size());
  };
  if (parallel_jobs <= 1) {
    for (std::size_t i = 0; i < jobs.size(); ++i) one(i);
  } else {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(parallel_jobs));
    tbb::parallel_for(std::size_t{0}, jobs.size(), one);
  }
  std::vector<Run> runs;
  for (auto& j : jobs) {
    if (!j.run.ok) spdlog::debug("bench: {} {} cell {} seed {}: {}", j.run.experiment, j.run.method, j.run.cell, j.run.seed, j.run.error);
    runs.push_back(j.run);
  }
  return runs;
}

Row Summarise(const std::vector<const Run*>& runs, std::map<std::string, std::string> labels) {
  Row row;
  row.labels = std::move(labels);
  row.runs = runs.size();
  std::vector<double> rms, add, translation, rotation, reg, total, mls, per_iteration;
  std::size_t successes = 0, within_20 = 0, said_ok = 0, mesh_good_successes = 0;
  std::vector<double> mesh_error, method_error, expected_error;
  std::size_t within_twice_expected = 0;
  for (const Run* r : runs) {
    row.peak_mb = std::max(row.peak_mb, r->peak_mb);
    if (r->mesh_error_m >= 0) {
      mesh_error.push_back(r->mesh_error_m * 1e3);
      if (r->mesh_error_m < kMeshGoodM) {
        ++row.mesh_good_runs;
        mesh_good_successes += r->ok && r->add_m <= kSuccessAddM;
      }
    }
    if (!r->ok) {
      ++row.errors;
      row.segmentation_flags += r->error.find("segmentation") != std::string::npos;
      continue;
    }
    successes += r->add_m <= kSuccessAddM;
    within_20 += r->add_m <= kWrongAddM;
    said_ok += r->status == "OK";
    // No robot in the cell: any OK is wrong.
    row.wrong_ok += r->status == "OK" && (r->add_m > kWrongAddM || r->scene_kind == "empty");
    rms.push_back(r->rms_m * 1e3), add.push_back(r->add_m * 1e3);
    translation.push_back(r->translation_m * 1e3), rotation.push_back(r->rotation_deg);
    if (r->stage_ms.count("register")) reg.push_back(r->stage_ms.at("register"));
    if (r->stage_ms.count("register") && r->iterations > 0)
      per_iteration.push_back(r->stage_ms.at("register") / r->iterations);
    if (r->stage_ms.count("mls")) mls.push_back(r->stage_ms.at("mls"));
    if (r->total_ms > 0) total.push_back(r->total_ms);
    if (r->method_error_m >= 0) method_error.push_back(r->method_error_m * 1e3);
    if (r->precision.valid) {
      expected_error.push_back(r->precision.expected_error_m * 1e3);
      within_twice_expected += r->add_m <= 2 * r->precision.expected_error_m;
    }
  }
  const double n = std::max<double>(1.0, static_cast<double>(runs.size()));
  row.success = static_cast<double>(successes) / n;
  row.within_20mm = static_cast<double>(within_20) / n;
  row.status_ok = static_cast<double>(said_ok) / n;
  row.rms_mean_mm = row.rms_min_mm = row.rms_max_mm = row.rms_std_mm = std::nan("");  // no successful run: no RMS
  if (!rms.empty()) {
    row.rms_mean_mm = std::accumulate(rms.begin(), rms.end(), 0.0) / static_cast<double>(rms.size());
    row.rms_min_mm = *std::min_element(rms.begin(), rms.end());
    row.rms_max_mm = *std::max_element(rms.begin(), rms.end());
    double sq = 0;
    for (double v : rms) sq += (v - row.rms_mean_mm) * (v - row.rms_mean_mm);
    row.rms_std_mm = std::sqrt(sq / static_cast<double>(rms.size()));  // population sigma, as the paper's table
  }
  row.add_median_mm = Quantile(add, 0.5), row.add_p95_mm = Quantile(add, 0.95);
  row.translation_median_mm = Quantile(translation, 0.5), row.rotation_median_deg = Quantile(rotation, 0.5);
  row.register_median_ms = Quantile(reg, 0.5), row.total_median_ms = Quantile(total, 0.5), row.mls_median_ms = Quantile(mls, 0.5);
  row.iteration_median_ms = Quantile(per_iteration, 0.5);
  row.mesh_error_median_mm = Quantile(mesh_error, 0.5);
  row.method_error_median_mm = Quantile(method_error, 0.5);
  row.expected_error_median_mm = Quantile(expected_error, 0.5);
  if (!expected_error.empty())
    row.within_twice_expected = static_cast<double>(within_twice_expected) / static_cast<double>(expected_error.size());
  if (row.mesh_good_runs) row.success_mesh_good = static_cast<double>(mesh_good_successes) / static_cast<double>(row.mesh_good_runs);
  return row;
}

}  // namespace arref::bench
