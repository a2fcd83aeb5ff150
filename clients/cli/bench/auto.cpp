// `arref bench --only auto`: seedless referencing on whole simulated rooms (sim/room_simulator.h)
// for every robot, both meshers, rooms with 0, 1 and 2 arms of the requested model (every other
// room also holds an arm of another model), for the product's method, the paper's sliding box and
// the global methods run over the whole map. Writes auto.md and auto_runs.csv into --out.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <fstream>
#include <map>

#include "arref/base/builtin.h"
#include "arref/base/split_mix.h"
#include "arref/base/stats.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/fusion/robot_side.h"
#include "arref/pipeline/seedless.h"
#include "arref/scene/metrics.h"
#include "arref/sim/room_simulator.h"
#include "bench.h"

namespace arref::bench {
namespace {

struct AutoRun {
  std::string robot, mesher, method, other;
  int arms = 0, room = 0;
  std::size_t triangles = 0;
  bool ok = false;
  std::string error, status;
  double primary_add_m = std::nan("");  // the primary instance to the nearest requested arm
  int instances = 0, arms_found = 0, wrong_ok = 0, candidates = 0;
  int arms_near = 0;  // arms within kWrongAddM of an instance: found, if not within kSuccessAddM
  // Per requested arm: its mesh error (sim::RoomArm::mesh_error_add_m; NaN: not measured), the
  // ADD of the instance nearest it (inf: no instance), and that instance's ADD against where the
  // mesh put the arm: what the method adds (NaN: not measured or no instance), and that
  // instance's expected error (FitPrecision; NaN: no instance).
  struct ArmFit {
    double mesh = std::nan(""), fit = std::numeric_limits<double>::infinity(), method = std::nan(""), expected = std::nan("");
  };
  std::vector<ArmFit> arm_fits;
  double ms = 0;
  std::map<std::string, double> stage_ms;
};


// A seeded method run as a seeded request at each requested arm's true pose (--auto-truth-seeds):
// no search, so what is left is the fit's own error on the room's map, as the robustness
// experiment's truth seeds measure it on cells.
Result<WholeMapReport> SeededAtEachArm(const RobotSide& side, const TriangleMesh& scene,
                                       const std::vector<const sim::RoomArm*>& arms, const RegistrationOptions& o) {
  WholeMapReport out;
  out.method = MethodName(o.method);
  for (const sim::RoomArm* a : arms) {
    ARREF_ASSIGN_OR_RETURN(RegistrationReport report, RegisterScene(side, scene, a->T_world_base, o));
    for (const auto& t : report.timings) out.timings.push_back(t);
    if (report.status != ResultStatus::kFailed) out.instances.push_back({std::move(report)});
  }
  out.candidates = static_cast<int>(arms.size());
  out.primary = out.instances.empty() ? -1 : 0;
  if (!out.instances.empty()) out.status = out.instances.front().report.status;
  return out;
}

// One room, every method: simulate, build the robot side once (untimed, as the server caches it),
// then each method over the whole map against the room's ground truth.
std::vector<AutoRun> RunRoom(const BenchRobot& robot, const BenchRobot* other, sim::Mesher mesher, int arms, int index,
                             std::uint64_t seed, const Config& config) {
  const std::vector<std::string>& methods = config.auto_methods;
  AutoRun label;
  label.robot = robot.label, label.mesher = sim::MesherName(mesher), label.arms = arms, label.room = index;
  label.other = other ? other->label : "";
  std::vector<AutoRun> runs;
  auto fail_all = [&](const Status& st) {
    for (const auto& m : methods) {
      AutoRun r = label;
      r.method = m, r.error = st.ToString();
      runs.push_back(r);
    }
    return runs;
  };
  sim::RoomOptions options;
  options.arms = arms, options.other_arm = other != nullptr, options.mesher = mesher;
  options.without = config.robustness.without;
  auto room = sim::SimulateRoom({robot.model.get(), other ? other->model.get() : nullptr}, options, seed);
  if (!room.ok()) return fail_all(room.status());
  SpatialMesh map;
  for (auto& s : room->surfaces)
    if (auto st = map.Upsert(s); !st.ok()) return fail_all(st);
  const TriangleMesh scene = *map.MergedWorld();
  label.triangles = scene.triangles.size();
  std::vector<const sim::RoomArm*> requested;
  for (const auto& a : room->arms)
    if (a.requested) requested.push_back(&a);
  const RegistrationOptions defaults;
  auto side = RobotSide::Create(*robot.model, requested.empty() ? JointValues{} : requested.front()->joints,
                                defaults.model_samples, defaults.sample_seed);
  if (!side.ok()) return fail_all(side.status());
  if (auto warm = (*side)->Expected(MedianEdgeLength(scene)); !warm.ok()) return fail_all(warm.status());
  const std::vector<Vec3f>& points = (*side)->samples().points;
  auto add_to = [&](const Iso3& T, const sim::RoomArm& a) { return ComparePoses(T, a.T_world_base, points).add_m; };
  for (const auto& method : methods) {
    AutoRun r = label;
    r.method = method;
    RegistrationOptions o;
    o.method = *ParseMethod(method);  // checked by the command
    if (config.head_path) o.head_path_world = room->head_path_world;
    const MethodInfo* info = FindMethod(o.method);  // the registry says which methods take a seed
    auto report = config.auto_truth_seeds && info && !info->seedless ? SeededAtEachArm(**side, scene, requested, o)
                                                                     : RegisterWholeMap(**side, scene, o);
    if (!report.ok()) {
      r.error = report.status().ToString();
      runs.push_back(r);
      continue;
    }
    r.ok = true;
    r.status = ResultStatusName(report->status);
    r.instances = static_cast<int>(report->instances.size());
    r.candidates = report->candidates;
    r.ms = report->total_ms();
    for (const auto& t : report->timings) r.stage_ms[t.stage] += t.ms;
    for (const auto& f : report->instances) {
      double nearest = std::numeric_limits<double>::infinity();
      for (const auto* a : requested) nearest = std::min(nearest, add_to(f.report.T_world_base, *a));
      r.wrong_ok += f.report.status == ResultStatus::kOk && nearest > kWrongAddM;
      spdlog::debug("bench: auto: {} {} room {} ({} arms): instance at ({:.2f}, {:.2f}) {} inliers {:.3f} score {:.3f} margin {:.3f} "
                    "detection {:.3f} explained {:.3f} (bar {:.3f}), {:.1f} mm from the nearest arm",
                    robot.label, label.mesher, index, arms, f.report.T_world_base.translation().x(),
                    f.report.T_world_base.translation().y(), ResultStatusName(f.report.status), f.report.inlier_fraction,
                    f.report.score, f.report.margin, f.detection_score, f.explained, f.explained_bar, nearest * 1000);
    }
    if (report->primary >= 0 && !requested.empty()) {
      double nearest = std::numeric_limits<double>::infinity();
      for (const auto* a : requested)
        nearest = std::min(nearest, add_to(report->instances[static_cast<std::size_t>(report->primary)].report.T_world_base, *a));
      r.primary_add_m = nearest;
    }
    auto found_within = [&](const sim::RoomArm& a, double add_m) {
      return std::any_of(report->instances.begin(), report->instances.end(),
                         [&](const FoundInstance& f) { return add_to(f.report.T_world_base, a) <= add_m; });
    };
    for (const auto* a : requested) r.arms_found += found_within(*a, kSuccessAddM), r.arms_near += found_within(*a, kWrongAddM);
    for (const auto* a : requested) {
      AutoRun::ArmFit arm;
      const FoundInstance* nearest = nullptr;
      for (const auto& f : report->instances)
        if (const double add = add_to(f.report.T_world_base, *a); add < arm.fit) arm.fit = add, nearest = &f;
      if (nearest && nearest->report.precision.valid) arm.expected = nearest->report.precision.expected_error_m;
      if (a->T_world_base_mesh) {
        arm.mesh = a->mesh_error_add_m;
        if (nearest) arm.method = ComparePoses(nearest->report.T_world_base, *a->T_world_base_mesh, points).add_m;
      }
      r.arm_fits.push_back(arm);
    }
    runs.push_back(r);
  }
  spdlog::info("bench: auto: {} {} room {} ({} arms{}, {} triangles) done", robot.label, label.mesher, index, arms,
               other ? ", with a " + other->label : "", label.triangles);
  return runs;
}

std::string Pct(std::size_t n, std::size_t of) { return of == 0 ? "-" : fmt::format("{:.0f} % ({}/{})", 100.0 * n / of, n, of); }

void Row(std::ostream& md, const std::string& method, const std::string& robot, const std::string& mesher,
         const std::vector<const AutoRun*>& rs) {
  std::size_t with_arm = 0, success = 0, near = 0, empty = 0, empty_failed = 0, two = 0, both = 0, both_near = 0, wrong = 0,
              errors = 0;
  std::vector<double> ms, found;
  for (const AutoRun* r : rs) {
    if (!r->ok) {
      ++errors;
      with_arm += r->arms > 0, empty += r->arms == 0, two += r->arms == 2;
      continue;
    }
    wrong += r->wrong_ok > 0;
    ms.push_back(r->ms);
    found.push_back(r->instances);
    if (r->arms == 0) {
      ++empty;
      empty_failed += r->status == "FAILED";
    } else {
      ++with_arm;
      success += r->primary_add_m <= kSuccessAddM;
      near += r->primary_add_m <= kWrongAddM;
    }
    if (r->arms == 2) ++two, both += r->arms_found == 2, both_near += r->arms_near == 2;
  }
  double mean_found = 0;
  for (double f : found) mean_found += f / static_cast<double>(std::max<std::size_t>(1, found.size()));
  md << fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2f} | {:.0f} | {:.0f} | {} |\n", method, robot, mesher,
                    rs.size(), Pct(success, with_arm), Pct(near, with_arm), wrong, Pct(empty_failed, empty), Pct(both, two),
                    Pct(both_near, two), mean_found, Quantile(ms, 0.5), Quantile(ms, 0.95), errors);
}

// Arms by where the headset's errors put them in the map (their mesh error): a fit that explains
// the map perfectly lands there, so an arm whose mesh error is over 10 mm cannot be fitted within
// 10 mm by any method; those under it measure the method.
void MeshErrorSection(std::ostream& md, const std::vector<AutoRun>& runs, const std::vector<std::string>& methods) {
  md << "\n## The mesh's error or the method's? (every requested arm)\n\n"
        "mesh error: the ADD of the rigid motion by which the headset's errors moved the arm in the map "
        "(per-view tracking error and, on Open3D, the surfaces' own errors); an arm fitted perfectly to the map lands "
        "there.\n\n| method | mesher | arms | mesh error median mm | mesh error under 5 mm: fitted within 10 mm | "
        "5-10 mm: within 10 mm | > 10 mm | not measured | the fit's ADD from where the mesh put the arm, median mm | "
        "ADD <= 2x the instance's expected error |\n|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& m : methods)
    for (const std::string mesher : {"own", "open3d", "all"}) {
      std::vector<double> mesh, added;
      std::size_t rated = 0, within_twice = 0;  // arms with an instance that states its expected error
      std::size_t arms = 0, low = 0, low_fit = 0, mid = 0, mid_fit = 0, high = 0, unmeasured = 0;
      for (const AutoRun& r : runs) {
        if (!r.ok || r.method != m || (mesher != "all" && r.mesher != mesher)) continue;
        for (const auto& [e, fit, method, expected] : r.arm_fits) {
          if (!std::isnan(expected) && std::isfinite(fit)) ++rated, within_twice += fit <= 2 * expected;
          ++arms;
          if (std::isnan(e)) {
            ++unmeasured;
            continue;
          }
          mesh.push_back(e * 1e3);
          if (!std::isnan(method)) added.push_back(method * 1e3);
          if (e < kMeshGoodM) ++low, low_fit += fit <= kSuccessAddM;  // as the cells' table
          else if (e <= kSuccessAddM) ++mid, mid_fit += fit <= kSuccessAddM;
          else ++high;
        }
      }
      if (arms == 0) continue;
      md << fmt::format("| {} | {} | {} | {:.1f} | {} | {} | {} | {} | {:.1f} | {} |\n", m, mesher, arms, Quantile(mesh, 0.5),
                        Pct(low_fit, low), Pct(mid_fit, mid), high, unmeasured, Quantile(added, 0.5), Pct(within_twice, rated));
    }
}

Status Write(const Config& config, const std::vector<AutoRun>& runs, const std::vector<std::string>& methods,
             const std::vector<std::string>& robots) {
  const std::string& dir = config.out_dir;
  std::ofstream csv(dir + "/auto_runs.csv");
  if (!csv) return Status::IoError("cannot write " + dir + "/auto_runs.csv");
  csv << "method,robot,mesher,arms,other,room,triangles,error,status,primary_add_mm,instances,arms_found,arms_found_20mm,wrong_ok,candidates,ms,stages,arm_mesh_error_mm,arm_fit_add_mm,arm_method_error_mm,arm_expected_error_mm\n";
  for (const AutoRun& r : runs) {
    std::string stages;
    for (const auto& [s, ms] : r.stage_ms) stages += fmt::format("{}={:.1f};", s, ms);
    std::string mesh, fit, method, expected;  // per requested arm, ';'-separated
    for (const auto& a : r.arm_fits) {
      mesh += fmt::format("{:.2f};", a.mesh * 1e3), fit += fmt::format("{:.2f};", a.fit * 1e3);
      method += fmt::format("{:.2f};", a.method * 1e3), expected += fmt::format("{:.2f};", a.expected * 1e3);
    }
    csv << fmt::format("{},{},{},{},{},{},{},\"{}\",{},{:.2f},{},{},{},{},{},{:.1f},{},{},{},{},{}\n", r.method, r.robot, r.mesher, r.arms,
                       r.other, r.room, r.triangles, r.error, r.status, r.primary_add_m * 1e3, r.instances, r.arms_found,
                       r.arms_near, r.wrong_ok, r.candidates, r.ms, stages, mesh, fit, method, expected);
  }
  std::ofstream md(dir + "/auto.md");
  if (!md) return Status::IoError("cannot write " + dir + "/auto.md");
  md << "# arref bench --only auto (" << config.robustness.split << " split)\n\n";
  md << "success: rooms with the arm whose primary instance is within ADD 10 mm of a requested arm; wrong OK: rooms "
        "with an instance said OK more than 20 mm from every requested arm; empty FAILED: rooms without the arm "
        "whose result is FAILED; both found: 2-arm rooms with both arms within 10 mm of an instance; the 20 mm "
        "columns count the same within 20 mm (the arm found, its fit not within 10 mm); ms: the whole request "
        "(robot side cached), median and p95.\n\n";
  if (!config.robustness.without.empty())
    md << fmt::format("Headset errors taken out of every room (a diagnostic): {}.\n\n", fmt::join(config.robustness.without, ", "));
  if (config.auto_truth_seeds) md << "Seeded methods start at each requested arm's true pose (a diagnostic).\n\n";
  md << "| method | robot | mesher | rooms | success | within 20 mm | wrong OK | empty FAILED | both found | both within 20 mm | "
        "instances (mean) | ms median | ms p95 | errors |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  auto select = [&](const std::string& m, const std::string& robot, const std::string& mesher) {
    std::vector<const AutoRun*> out;
    for (const AutoRun& r : runs)
      if (r.method == m && (robot == "all" || r.robot == robot) && (mesher == "all" || r.mesher == mesher)) out.push_back(&r);
    return out;
  };
  for (const auto& m : methods) {
    for (const auto& robot : robots)
      for (const auto& mesher : config.robustness.meshers) Row(md, m, robot, mesher, select(m, robot, mesher));
    for (const auto& mesher : config.robustness.meshers) Row(md, m, "all", mesher, select(m, "all", mesher));
    Row(md, m, "all", "all", select(m, "all", "all"));
  }
  MeshErrorSection(md, runs, methods);
  md << "\n## Where arref-auto's time goes (median ms per stage)\n\n| stage | median ms | p95 ms |\n|---|---|---|\n";
  std::map<std::string, std::vector<double>> per_stage;
  std::vector<double> tris;
  for (const AutoRun& r : runs)
    if (r.ok && r.method == "arref-auto") {
      for (const auto& [s, ms] : r.stage_ms) per_stage[s].push_back(ms);
      tris.push_back(static_cast<double>(r.triangles));
    }
  for (const auto& [s, v] : per_stage) md << fmt::format("| {} | {:.1f} | {:.1f} |\n", s, Quantile(v, 0.5), Quantile(v, 0.95));
  md << fmt::format("\nMap triangles: median {:.0f}, min {:.0f}, max {:.0f}.\n", Quantile(tris, 0.5), Quantile(tris, 0), Quantile(tris, 1));
  return md ? Status::Ok() : Status::IoError("error writing " + dir + "/auto.md");
}

}  // namespace

Status AutoExperiment(const Config& config, Tables* tables) {
  const RobustnessConfig& rc = config.robustness;
  const bool heldout = rc.split == "heldout";
  ARREF_ASSIGN_OR_RETURN(const std::vector<BenchRobot> robots, LoadBenchRobots(rc, heldout, "auto"));
  std::vector<sim::Mesher> meshers;
  for (const auto& name : rc.meshers) {
    ARREF_ASSIGN_OR_RETURN(const sim::Mesher m, sim::ParseMesher(name));
    if (!sim::MesherAvailable(m)) return Status::FailedPrecondition("auto: mesher " + name + " is not built in (Open3D missing)");
    meshers.push_back(m);
  }
  for (const auto& m : config.auto_methods)
    if (auto parsed = ParseMethod(m); !parsed.ok()) return parsed.status().WithContext("--auto-methods");
  // The held-back split draws its rooms from a stream of its own.
  const std::uint64_t stream = heldout ? SplitMix64(config.rng_seed ^ 0x4155544Fu ^ 0x48454C44u) : SplitMix64(config.rng_seed ^ 0x4155544Fu);
  struct Task {
    std::size_t robot;
    sim::Mesher mesher;
    int arms, index;
    std::uint64_t seed;
  };
  std::vector<Task> tasks;
  const int per = config.quick ? 1 : config.auto_rooms;
  for (std::size_t r = 0; r < robots.size(); ++r)
    for (int arms : config.auto_arms)
      for (int i = 0; i < per; ++i) {
        const std::uint64_t seed = SplitMix64(stream ^ SplitMix64(std::hash<std::string>{}(robots[r].label)) ^ SplitMix64(static_cast<std::uint64_t>(arms * 1000 + i + 1)));
        for (sim::Mesher m : meshers) tasks.push_back({r, m, arms, i, seed});  // the same room layout for both meshers
      }
  spdlog::info("bench: auto ({} split): {} robots, {} rooms, methods {}", rc.split, robots.size(), tasks.size(),
               fmt::join(config.auto_methods, ", "));
  std::vector<std::vector<AutoRun>> results(tasks.size());
  auto one = [&](std::size_t t) {
    const Task& k = tasks[t];
    // Every other room holds an arm of the next robot too, when there is another.
    const BenchRobot* other = robots.size() > 1 && k.index % 2 == 1 ? &robots[(k.robot + 1) % robots.size()] : nullptr;
    results[t] = RunRoom(robots[k.robot], other, k.mesher, k.arms, k.index, k.seed, config);
  };
  if (config.jobs <= 1) {
    for (std::size_t t = 0; t < tasks.size(); ++t) one(t);
  } else {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(config.jobs));
    tbb::parallel_for(std::size_t{0}, tasks.size(), one);
  }
  std::vector<AutoRun> runs;
  for (auto& r : results) runs.insert(runs.end(), r.begin(), r.end());
  std::vector<std::string> labels;
  for (const auto& r : robots) labels.push_back(r.label);
  ARREF_RETURN_IF_ERROR(Write(config, runs, config.auto_methods, labels));
  tables->notes.push_back(fmt::format("auto: {} split, {} rooms, {} room(s) per robot and arm count and mesher{}; tables in auto.md",
                                      rc.split, tasks.size(), per,
                                      config.head_path ? ", each request sending the wearer's path" : ""));
  return Status::Ok();
}

}  // namespace arref::bench
