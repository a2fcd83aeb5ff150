// The paper's experiments (Puljiz et al. 2019, Sec. V), on simulated cells with ground truth:
// the parameter sweep (Tables I and II), the seed perturbations (Table III and its figure),
// and every method on each kind of scene (which the paper could not measure).
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <deque>
#include <functional>
#include <map>
#include <numbers>

#include "arref/base/builtin.h"
#include "arref/base/split_mix.h"
#include "arref/robot/robot_model.h"
#include "bench.h"

namespace arref::bench {
namespace {

const std::vector<std::string> kAllKinds = {"default", "near-table", "clutter", "second-robot"};

struct ParamSet {
  std::string label;
  IcpParams icp;
  std::optional<MlsOptions> mls;
};

// The paper's ranges: max correspondence distance, max iterations, MLS off or with search
// radius 0.005 / 0.05 m, with or without upsampling (on the big configuration upsampling makes
// ~3 million points and ~15 s per run).
std::vector<ParamSet> SweepSets(bool quick) {
  const std::vector<double> distances = quick ? std::vector<double>{0.05, 0.1} : std::vector<double>{0.05, 0.1, 0.2};
  const std::vector<int> iterations = {50, 500};
  std::vector<std::pair<std::string, std::optional<MlsOptions>>> mls = {{"off", std::nullopt}};
  if (!quick) mls.push_back({"0.005", MlsOptions{.search_radius_m = 0.005}});
  mls.push_back({"0.05", MlsOptions{.search_radius_m = 0.05}});
  if (!quick)
    mls.push_back({"0.05+upsampling", MlsOptions{.search_radius_m = 0.05,
                                                 .upsampling = MlsOptions::Upsampling::kSampleLocalPlane,
                                                 .upsampling_radius_m = 0.02,
                                                 .upsampling_step_m = 0.01}});
  std::vector<ParamSet> sets;
  for (double d : distances)
    for (int it : iterations)
      for (const auto& [name, m] : mls) {
        ParamSet s{fmt::format("dist {:.2f} m, {} it, MLS {}", d, it, name), {}, m};
        s.icp.max_correspondence_m = d;
        s.icp.max_iterations = it;
        sets.push_back(s);
      }
  return sets;
}

RegistrationOptions BaseOptions(const std::string& method, const std::string& size) {
  RegistrationOptions o;
  o.method = *ParseMethod(method);  // checked by the command
  o.scene_samples = size == "big" ? 256000 : 16000;
  return o;
}

// A mesh voxel's whole centimetres, and their band ("4-5 cm"): the robustness table's voxel
// label; "-" for none (a cell without a fused mesh).
int VoxelCm(double voxel_m) { return static_cast<int>(std::floor(voxel_m * 100 + 1e-9)); }
std::string VoxelBand(double voxel_m) {
  return voxel_m > 0 ? fmt::format("{}-{} cm", VoxelCm(voxel_m), VoxelCm(voxel_m) + 1) : "-";
}

// The voxel bands of one method's runs on one mesher, finest first.
std::vector<std::string> VoxelBands(const std::vector<Run>& runs, const std::string& method, const std::string& mesher) {
  std::map<int, std::string> bands;
  for (const Run& r : runs)
    if (r.method == method && r.mesher == mesher && r.voxel_m > 0) bands.emplace(VoxelCm(r.voxel_m), VoxelBand(r.voxel_m));
  std::vector<std::string> out;
  for (const auto& [cm, band] : bands) out.push_back(band);
  return out;
}

Run Label(const std::string& experiment, const std::string& method, const std::string& size, const std::string& params,
          const Cell& cell, int seed) {
  Run r;
  r.experiment = experiment, r.method = method, r.size = size, r.params = params;
  r.scene_kind = cell.kind, r.cell = cell.index, r.seed = seed;
  return r;
}

// A registration of the cell from its s-th user-like seed, with the method's defaults.
Job SeedJob(const std::string& experiment, const std::string& method, const std::string& size,
            const std::string& params, const Cell& cell, int s) {
  Job job;
  job.cell = &cell;
  job.T_world_seed = cell.sim.seeds[s];
  job.options = BaseOptions(method, size);
  job.run = Label(experiment, method, size, params, cell, s);
  return job;
}

std::vector<const Run*> Select(const std::vector<Run>& runs, const std::function<bool(const Run&)>& keep) {
  std::vector<const Run*> out;
  for (const auto& r : runs)
    if (keep(r)) out.push_back(&r);
  return out;
}

void Append(Tables* tables, std::vector<Run> runs) {
  tables->runs.insert(tables->runs.end(), std::make_move_iterator(runs.begin()), std::make_move_iterator(runs.end()));
}

Status SweepSize(const RobotModel& robot, const Config& config, const std::string& size, Tables* tables) {
  const std::vector<std::string> kinds =
      config.quick ? std::vector<std::string>{"default", "near-table"} : kAllKinds;
  const int seeds = config.quick || size == "big" ? 1 : 2;  // big: one seed per kind (runs take seconds)
  auto cells = MakeCells(robot, kinds, size, 1, seeds, config.rng_seed);
  if (!cells.ok()) return cells.status();
  const auto sets = SweepSets(config.quick);
  std::vector<Job> jobs;
  for (const auto& method : config.methods)
    for (const auto& set : sets)
      for (const auto& cell : *cells)
        for (int s = 0; s < static_cast<int>(cell.sim.seeds.size()); ++s) {
          Job job = SeedJob("sweep", method, size, set.label, cell, s);
          job.options.icp = set.icp;
          job.options.mls = set.mls;
          jobs.push_back(job);
        }
  spdlog::info("bench: sweep, {} configuration: {} runs", size, jobs.size());
  const std::vector<Run> runs = Execute(jobs, config.jobs);
  for (const auto& method : config.methods) {
    const auto all = Select(runs, [&](const Run& r) { return r.method == method; });
    tables->table1.push_back(Summarise(all, {{"method", method}, {"size", size}}));
    // Table II: per parameter set; the best and worst by the paper's RMS, and the best by truth.
    std::vector<Row> per_set;
    for (const auto& set : sets)
      per_set.push_back(Summarise(Select(runs, [&](const Run& r) { return r.method == method && r.params == set.label; }),
                                  {{"method", method}, {"size", size}, {"params", set.label}}));
    auto by_rms = [](const Row& a, const Row& b) { return a.rms_mean_mm < b.rms_mean_mm; };
    auto by_add = [](const Row& a, const Row& b) {
      return a.success != b.success ? a.success > b.success : a.add_median_mm < b.add_median_mm;
    };
    // A set whose every run failed has no RMS: it can be neither best nor worst by RMS.
    std::erase_if(per_set, [](const Row& r) { return r.errors == r.runs; });
    if (per_set.empty()) continue;
    Row best = *std::min_element(per_set.begin(), per_set.end(), by_rms);
    Row worst = *std::max_element(per_set.begin(), per_set.end(), by_rms);
    Row truth = *std::min_element(per_set.begin(), per_set.end(), by_add);
    best.labels["rank"] = "best by RMS", worst.labels["rank"] = "worst by RMS", truth.labels["rank"] = "best by ADD";
    tables->table2.insert(tables->table2.end(), {best, worst, truth});
  }
  Append(tables, runs);
  return Status::Ok();
}

// The seed moved as in the paper: rotated about its own vertical axis, or shifted in world.
Iso3 Rotated(const Iso3& seed, double yaw_deg) {
  return seed * Iso3(Eigen::AngleAxisd(yaw_deg * std::numbers::pi / 180.0, Vec3::UnitZ()));
}

std::vector<Job> PerturbJobs(const Cell& cell, int s, const std::string& method, bool quick) {
  std::vector<Job> jobs;
  const bool guess = method.empty();  // the user's guess itself, no registration
  auto add = [&](const Iso3& T, const std::string& kind, double yaw, const Vec3& offset) {
    Job job;
    job.cell = &cell;
    job.T_world_seed = T;
    job.options = BaseOptions(guess ? "pcl-icp" : method, "small");
    job.seed_only = guess;
    job.run = Label("perturb", guess ? "user guess" : method, "small", kind, cell, s);
    job.run.seed_yaw_deg = yaw, job.run.seed_offset_m = offset, job.run.perturbation = kind;
    jobs.push_back(job);
  };
  const Iso3& seed = cell.sim.seeds[s];
  const std::vector<int> steps = quick ? std::vector<int>{0, 1, 2, 5, 10} : std::vector<int>{};
  for (int k = 0; k < 20; ++k)  // 18 degree steps round the circle
    if (!quick || std::find(steps.begin(), steps.end(), k) != steps.end()) add(Rotated(seed, 18.0 * k), "rotation", 18.0 * k, Vec3::Zero());
  const std::vector<double> offsets = quick ? std::vector<double>{-0.3, -0.1, 0.1, 0.3}
                                            : std::vector<double>{-0.5, -0.4, -0.3, -0.2, -0.1, 0.1, 0.2, 0.3, 0.4, 0.5};
  for (int axis = 0; axis < 3; ++axis)  // a 1 m cube in 0.1 m steps, along each of its axes
    for (double o : offsets) {
      Vec3 offset = Vec3::Zero();
      offset[axis] = o;
      add(Iso3(Eigen::Translation3d(offset)) * seed, "translation", 0.0, offset);
    }
  return jobs;
}

}  // namespace

Result<std::vector<BenchRobot>> LoadBenchRobots(const RobustnessConfig& rc, bool keep_heldout, const std::string& experiment) {
  std::vector<BenchRobot> robots;
  for (const auto& urdf : rc.robots) {
    std::string path = urdf;
    if (path == "builtin") {
      ARREF_ASSIGN_OR_RETURN(path, BuiltinRobotUrdf());
    }
    RobotLoadOptions load;
    load.package_path = rc.package_path;
    auto model = RobotModel::Load(path, load);
    if (!model.ok()) return model.status().WithContext("--robots " + urdf);
    const std::string name = model->name();
    // A package may hold the same robot twice (a URDF with package:// and one with relative paths).
    if (std::any_of(robots.begin(), robots.end(), [&](const BenchRobot& r) { return r.label == name; })) continue;
    const bool heldout = !rc.heldout_robot.empty() &&
                         (name.find(rc.heldout_robot) != std::string::npos || urdf.find(rc.heldout_robot) != std::string::npos);
    if (heldout && !keep_heldout) {
      spdlog::info("bench: {}, dev split: {} is held out", experiment, name);
      continue;
    }
    robots.push_back({name, urdf, std::make_shared<const RobotModel>(std::move(*model))});
  }
  if (robots.empty())
    return Status::InvalidArgument(experiment + ": no robot left to measure (--robots, --heldout-robot)");
  return robots;
}

Status RobustnessExperiment(const Config& config, Tables* tables) {
  const RobustnessConfig& rc = config.robustness;
  const bool heldout = rc.split == "heldout";
  auto robots = LoadBenchRobots(rc, heldout, "robustness");
  if (!robots.ok()) return robots.status();
  std::vector<sim::Mesher> meshers;
  for (const auto& name : rc.meshers) {
    auto m = sim::ParseMesher(name);
    if (!m.ok()) return m.status();
    if (!sim::MesherAvailable(*m)) return Status::FailedPrecondition("robustness: mesher " + name + " is not built in (Open3D missing)");
    meshers.push_back(*m);
  }
  std::vector<sim::SeedFamily> families;
  for (const auto& name : rc.seed_families) {
    auto f = sim::ParseSeedFamily(name);
    if (!f.ok()) return f.status();
    families.push_back(*f);
  }
  const int cells_per = config.quick ? 1 : rc.cells, seeds_per = config.quick ? 1 : rc.seeds;
  // The held-out split draws from a stream of its own: none of its cells or seeds was seen in
  // development.
  const std::uint64_t stream = heldout ? SplitMix64(config.rng_seed ^ 0x48454C44u) : SplitMix64(config.rng_seed ^ 0x444556u);
  std::deque<Cell> cells;  // stable addresses for the jobs
  std::vector<Job> jobs;
  for (std::size_t r = 0; r < robots->size(); ++r) {
    const BenchRobot& robot = (*robots)[r];
    for (int i = 0; i < cells_per; ++i) {
      const std::string& kind = kAllKinds[static_cast<std::size_t>(i) % kAllKinds.size()];
      // Keyed by the robot's name, not its place in --robots: a robot's cells stay the same
      // whichever others are measured with it.
      const std::uint64_t cell_seed = SplitMix64(stream ^ SplitMix64(std::hash<std::string>{}(robot.label)) ^ SplitMix64(static_cast<std::uint64_t>(i) + 1));
      std::shared_ptr<const RobotSide> side;
      for (sim::Mesher mesher : meshers) {
        auto cell = MakeCell(*robot.model, kind, i, cell_seed, mesher, side, rc);
        if (!cell.ok()) return cell.status();
        if (rc.motion == "none") side = cell->robot;  // else chosen per mesh (SetCellRobotSide)
        cells.push_back(std::move(*cell));
        const Cell& c = cells.back();
        for (sim::SeedFamily family : families) {
          sim::SeedNoise noise;
          noise.family = family;
          std::mt19937_64 seed_rng(SplitMix64(cell_seed ^ SplitMix64(0x5EED0000u + static_cast<std::uint64_t>(family))));
          const std::vector<Iso3> seeds = sim::DrawSeeds(c.sim.T_world_base, noise, seeds_per, seed_rng);
          for (const auto& method : rc.methods)
            for (int s = 0; s < seeds_per; ++s) {
              Job job;
              job.cell = &c;
              job.T_world_seed = seeds[static_cast<std::size_t>(s)];
              job.options = BaseOptions(method, "small");  // the 2 m crop, 16,000 scene samples
              job.options.map_not_as_posed = c.map_not_as_posed;
              if (config.head_path) job.options.head_path_world = c.sim.head_path_world;
              job.run = Label("robustness", method, "small", "", c, s);
              job.run.robot = robot.label, job.run.mesher = sim::MesherName(mesher);
              job.run.seed_family = sim::SeedFamilyName(family);
              job.run.mesh_error_m = c.sim.mesh_error_add_m;
              job.run.voxel_m = c.sim.voxel_m;
              job.run.params = fmt::format("{} {} {} seeds", robot.label, job.run.mesher, job.run.seed_family);
              jobs.push_back(job);
            }
        }
      }
    }
  }
  spdlog::info("bench: robustness ({} split): {} robots, {} cells, {} runs", rc.split, robots->size(), cells.size(), jobs.size());
  const std::vector<Run> runs = Execute(jobs, config.jobs);
  for (const auto& method : rc.methods) {
    auto add = [&](const std::string& robot, const std::string& mesher, const std::string& family,
                   const std::string& voxel = "all") {
      const auto selected = Select(runs, [&](const Run& r) {
        return r.method == method && (robot == "all" || r.robot == robot) && (mesher == "all" || r.mesher == mesher) &&
               (family == "all" || r.seed_family == family) && (voxel == "all" || VoxelBand(r.voxel_m) == voxel);
      });
      tables->robustness.push_back(Summarise(selected, {{"method", method}, {"split", rc.split}, {"robot", robot},
                                                        {"mesher", mesher}, {"seeds", family}, {"voxel", voxel}}));
    };
    for (const auto& robot : *robots)
      for (const auto& mesher : rc.meshers) add(robot.label, mesher, "all");
    for (const auto& robot : *robots) add(robot.label, "all", "all");
    for (const auto& mesher : rc.meshers) add("all", mesher, "all");
    for (const auto& mesher : rc.meshers)
      for (const auto& family : rc.seed_families) add("all", mesher, family);
    add("all", "all", "all");
    // Per mesher and voxel band, last: a coarse mesh costs the fit most (docs/robustness.md,
    // "The wrong OK on Open3D's meshes, traced").
    for (const auto& mesher : rc.meshers)
      for (const auto& band : VoxelBands(runs, method, mesher)) add("all", mesher, "all", band);
  }
  tables->notes.push_back(fmt::format("robustness: {} split{}, robots {}, {} cell(s) per robot and mesher, {} seed(s) per family",
                                      rc.split,
                                      (rc.motion == "none" ? std::string()
                                                           : fmt::format(" (joints moving while mapping: {}; fit: {})", rc.motion, rc.moving_fit)) +
                                          (rc.pedestals ? " (arms on pedestals)" : "") +
                                          (rc.own_voxels ? " (own mesher at voxels of 2-6 cm)" : "") +
                                          (config.head_path ? " (each request sends the wearer's path)" : ""),
                                      fmt::join([&] {
                                        std::vector<std::string> names;
                                        for (const auto& r : *robots) names.push_back(r.label);
                                        return names;
                                      }(), ", "), cells_per, seeds_per));
  Append(tables, runs);
  return Status::Ok();
}

Status SweepExperiment(const RobotModel& robot, const Config& config, Tables* tables) {
  ARREF_RETURN_IF_ERROR(SweepSize(robot, config, "small", tables));
  if (config.big && !config.quick) ARREF_RETURN_IF_ERROR(SweepSize(robot, config, "big", tables));
  return Status::Ok();
}

Status PerturbExperiment(const RobotModel& robot, const Config& config, Tables* tables) {
  // Twelve user guesses: three user-like seeds in each kind of cell (quick: two in one cell).
  const std::vector<std::string> kinds = config.quick ? std::vector<std::string>{"default"} : kAllKinds;
  auto cells = MakeCells(robot, kinds, "small", 1, config.quick ? 2 : 3, config.rng_seed + 7);
  if (!cells.ok()) return cells.status();
  std::vector<Job> jobs;
  std::vector<std::string> methods = {""};
  methods.insert(methods.end(), config.perturb_methods.begin(), config.perturb_methods.end());
  for (const auto& method : methods)
    for (const auto& cell : *cells)
      for (int s = 0; s < static_cast<int>(cell.sim.seeds.size()); ++s) {
        auto more = PerturbJobs(cell, s, method, config.quick);
        jobs.insert(jobs.end(), more.begin(), more.end());
      }
  spdlog::info("bench: seed perturbations: {} runs", jobs.size());
  const std::vector<Run> runs = Execute(jobs, config.jobs);
  const auto guesses = Select(runs, [](const Run& r) { return r.method == "user guess"; });
  tables->table3.push_back(Summarise(guesses, {{"method", "user guess"}, {"set", "all"}}));
  for (const auto& method : config.perturb_methods) {
    tables->table3.push_back(Summarise(Select(runs, [&](const Run& r) { return r.method == method; }),
                                       {{"method", method}, {"set", "all"}}));
    for (const char* kind : {"rotation", "translation"})
      tables->table3.push_back(Summarise(
          Select(runs, [&](const Run& r) { return r.method == method && r.perturbation == kind; }),
          {{"method", method}, {"set", kind}}));
  }
  Append(tables, runs);
  return Status::Ok();
}

Status ScenesExperiment(const RobotModel& robot, const Config& config, Tables* tables) {
  const std::vector<std::string> kinds =
      config.quick ? std::vector<std::string>{"default", "near-table"} : config.scene_kinds;
  const std::string& size = config.scene_size;
  auto cells = MakeCells(robot, kinds, size, config.quick ? 1 : config.scene_cells, config.quick ? 2 : config.scene_seeds,
                         config.rng_seed + 13, config.variation);
  if (!cells.ok()) return cells.status();
  std::vector<Job> jobs;
  for (const auto& method : config.scene_methods)
    for (const auto& cell : *cells)
      for (int s = 0; s < static_cast<int>(cell.sim.seeds.size()); ++s) {
        jobs.push_back(SeedJob("scenes", method, size, "defaults", cell, s));
        if (config.head_path) jobs.back().options.head_path_world = cell.sim.head_path_world;
        if (config.tracking_error_m >= 0)
          jobs.back().options.arref_icp.tracking_error = {config.tracking_error_m, 75.0 * config.tracking_error_m};
        if (!config.images_dir.empty() && s == 0)
          jobs.back().image_path = fmt::format("{}/scenes_{}_{}_{}.png", config.images_dir, method, cell.kind, cell.index);
      }
  spdlog::info("bench: methods on each kind of scene: {} runs", jobs.size());
  const std::vector<Run> runs = Execute(jobs, config.jobs);
  for (const auto& method : config.scene_methods) {
    for (const auto& kind : kinds)
      tables->scenes.push_back(Summarise(Select(runs, [&](const Run& r) { return r.method == method && r.scene_kind == kind; }),
                                         {{"method", method}, {"scene", kind}}));
    // Cells without a robot have no right answer: they count only for "wrong OK".
    tables->scenes.push_back(
        Summarise(Select(runs, [&](const Run& r) { return r.method == method && r.scene_kind != "empty"; }),
                  {{"method", method}, {"scene", "all with a robot"}}));
  }
  Append(tables, runs);
  return Status::Ok();
}

}  // namespace arref::bench
