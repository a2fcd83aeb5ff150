// The bench's output: markdown tables (results.md), CSV files and gnuplot PNG figures.
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <set>

#include "arref/base/stats.h"
#include "bench.h"

namespace arref::bench {
namespace {

std::string Num(double v, int digits = 1) { return std::isfinite(v) ? fmt::format("{:.{}f}", v, digits) : "-"; }

struct Column {
  const char* name;
  std::function<std::string(const Row&)> value;
};

const std::vector<Column>& StatColumns() {
  static const std::vector<Column> kColumns = {
      {"runs", [](const Row& r) { return std::to_string(r.runs); }},
      {"errors (segmentation)", [](const Row& r) { return fmt::format("{} ({})", r.errors, r.segmentation_flags); }},
      {"RMS mean mm", [](const Row& r) { return Num(r.rms_mean_mm, 2); }},
      {"RMS min", [](const Row& r) { return Num(r.rms_min_mm, 2); }},
      {"RMS max", [](const Row& r) { return Num(r.rms_max_mm, 2); }},
      {"RMS sigma", [](const Row& r) { return Num(r.rms_std_mm, 2); }},
      {"success (ADD<=10mm)", [](const Row& r) { return Num(r.success * 100, 0) + " %"; }},
      {"ADD<=20mm", [](const Row& r) { return Num(r.within_20mm * 100, 0) + " %"; }},
      {"said OK", [](const Row& r) { return Num(r.status_ok * 100, 0) + " %"; }},
      {"wrong OK", [](const Row& r) { return std::to_string(r.wrong_ok); }},
      {"ADD median mm", [](const Row& r) { return Num(r.add_median_mm); }},
      {"ADD p95 mm", [](const Row& r) { return Num(r.add_p95_mm); }},
      {"transl. median mm", [](const Row& r) { return Num(r.translation_median_mm); }},
      {"rot. median deg", [](const Row& r) { return Num(r.rotation_median_deg, 2); }},
      {"register median ms", [](const Row& r) { return Num(r.register_median_ms, 0); }},
      {"ms per iteration", [](const Row& r) { return Num(r.iteration_median_ms, 3); }},
      {"MLS median ms", [](const Row& r) { return Num(r.mls_median_ms, 0); }},
      {"total median ms", [](const Row& r) { return Num(r.total_median_ms, 0); }},
      {"peak MB", [](const Row& r) { return Num(r.peak_mb, 0); }},
  };
  return kColumns;
}

// The robustness table adds how far the mesh itself put the robot (the Open3D mesher's
// per-surface head-pose errors), to tell the mesh's error from the method's, and how the
// results' own expected error compares with their ADD.
const std::vector<Column>& RobustnessColumns() {
  static const std::vector<Column> kColumns = [] {
    std::vector<Column> c = StatColumns();
    c.push_back({"mesh error median mm", [](const Row& r) { return Num(r.mesh_error_median_mm); }});
    c.push_back({"method error median mm", [](const Row& r) { return Num(r.method_error_median_mm); }});
    c.push_back({"success where mesh error < 5 mm",
                 [](const Row& r) { return r.mesh_good_runs ? Num(r.success_mesh_good * 100, 0) + " % of " + std::to_string(r.mesh_good_runs) : "-"; }});
    c.push_back({"expected error median mm", [](const Row& r) { return Num(r.expected_error_median_mm); }});
    c.push_back({"ADD <= 2x expected",
                 [](const Row& r) { return std::isnan(r.within_twice_expected) ? "-" : Num(r.within_twice_expected * 100, 0) + " %"; }});
    return c;
  }();
  return kColumns;
}

void MarkdownTable(std::ostream& out, const std::vector<Row>& rows, const std::vector<std::string>& labels,
                   const std::vector<Column>& columns = StatColumns()) {
  out << "|";
  for (const auto& l : labels) out << " " << l << " |";
  for (const auto& c : columns) out << " " << c.name << " |";
  out << "\n|";
  for (std::size_t i = 0; i < labels.size() + columns.size(); ++i) out << "---|";
  out << "\n";
  for (const auto& row : rows) {
    out << "|";
    for (const auto& l : labels) out << " " << (row.labels.count(l) ? row.labels.at(l) : "") << " |";
    for (const auto& c : columns) out << " " << c.value(row) << " |";
    out << "\n";
  }
  out << "\n";
}

std::string Csv(const std::string& s) { return s.find(',') == std::string::npos ? s : "\"" + s + "\""; }

Status CsvTable(const std::string& path, const std::vector<Row>& rows, const std::vector<std::string>& labels,
                const std::vector<Column>& columns = StatColumns()) {
  std::ofstream out(path);
  if (!out) return Status::IoError("cannot write " + path);
  std::vector<std::string> header = labels;
  for (const auto& c : columns) header.push_back(c.name);
  for (std::size_t i = 0; i < header.size(); ++i) out << (i ? "," : "") << Csv(header[i]);
  out << "\n";
  for (const auto& row : rows) {
    for (std::size_t i = 0; i < labels.size(); ++i) out << (i ? "," : "") << Csv(row.labels.count(labels[i]) ? row.labels.at(labels[i]) : "");
    for (const auto& c : columns) out << "," << Csv(c.value(row));
    out << "\n";
  }
  return out ? Status::Ok() : Status::IoError("error writing " + path);
}

Status RunsCsv(const std::string& path, const std::vector<Run>& runs) {
  std::ofstream out(path);
  if (!out) return Status::IoError("cannot write " + path);
  out << "experiment,method,size,params,scene,cell,seed,perturbation,seed_yaw_deg,offset_x,offset_y,offset_z,ok,status,"
         "rms_mm,add_mm,translation_mm,rotation_deg,crop_ms,sample_ms,mls_ms,register_ms,total_ms,peak_mb,iterations,error,"
         "mesh_error_mm,vertical_mm,horizontal_mm,steps,expected_error_mm,sigma_horizontal_mm,sigma_vertical_mm,"
         "sigma_yaw_deg,fit_error_mm,map_error_mm,surface_error_mm,stages,method_error_mm,voxel_mm\n";
  auto stage = [](const Run& r, const char* s) { return r.stage_ms.count(s) ? Num(r.stage_ms.at(s), 1) : ""; };
  // Every stage and method step ("register/pose-search=12.3;..."), for per-step profiles.
  auto steps = [](const Run& r) {
    std::string all;
    for (const auto& [name, ms] : r.stage_ms) all += fmt::format("{}={};", name, Num(ms, 1));
    return all;
  };
  auto precision = [](const Run& r) {
    const FitPrecision& p = r.precision;
    if (!p.valid) return std::string(",,,,,,");
    return fmt::format("{},{},{},{},{},{},{}", Num(p.expected_error_m * 1e3, 2), Num(p.sigma_horizontal_m() * 1e3, 2),
                       Num(p.sigma_vertical_m() * 1e3, 2), Num(p.sigma_yaw_rad() * 180.0 / std::numbers::pi, 3),
                       Num(p.fit_error_m * 1e3, 2), Num(p.map_error_m * 1e3, 2), Num(p.surface_error_m * 1e3, 2));
  };
  for (const auto& r : runs)
    out << fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", r.experiment, Csv(r.method),
                       r.size, Csv(r.params), r.scene_kind, r.cell, r.seed, r.perturbation, r.seed_yaw_deg,
                       r.seed_offset_m.x(), r.seed_offset_m.y(), r.seed_offset_m.z(), r.ok ? 1 : 0, r.status, Num(r.rms_m * 1e3, 3),
                       Num(r.add_m * 1e3, 3), Num(r.translation_m * 1e3, 3), Num(r.rotation_deg, 3), stage(r, "crop"),
                       stage(r, "sample"), stage(r, "mls"), stage(r, "register"), Num(r.total_ms, 1), Num(r.peak_mb, 0),
                       r.iterations, Csv(r.error), r.mesh_error_m >= 0 ? Num(r.mesh_error_m * 1e3, 2) : "",
                       Num(r.vertical_m * 1e3, 3), Num(r.horizontal_m * 1e3, 3), Csv(steps(r)), precision(r), Csv(r.stages),
                       r.method_error_m >= 0 ? Num(r.method_error_m * 1e3, 2) : "",
                       r.voxel_m > 0 ? Num(r.voxel_m * 1e3, 1) : "");
  return out ? Status::Ok() : Status::IoError("error writing " + path);
}

// One line per x value: mean/min/max RMS and median ADD of each method's perturbation runs.
Status PlotData(const std::string& path, const std::vector<Run>& runs, const std::vector<std::string>& methods,
                const std::string& perturbation, const std::function<double(const Run&)>& x) {
  std::map<double, std::map<std::string, std::vector<const Run*>>> groups;
  for (const auto& r : runs)
    if (r.experiment == "perturb" && r.perturbation == perturbation && r.ok) groups[x(r)][r.method].push_back(&r);
  std::ofstream out(path);
  if (!out) return Status::IoError("cannot write " + path);
  out << "# x";
  for (const auto& m : methods) out << fmt::format(" '{0} RMS mean' '{0} RMS min' '{0} RMS max' '{0} ADD median'", m);
  out << "\n";
  for (const auto& [value, by_method] : groups) {
    out << value;
    for (const auto& m : methods) {
      const auto it = by_method.find(m);
      const Row row = Summarise(it == by_method.end() ? std::vector<const Run*>{} : it->second, {});
      out << " " << Num(row.rms_mean_mm, 3) << " " << Num(row.rms_min_mm, 3) << " " << Num(row.rms_max_mm, 3) << " "
          << Num(row.add_median_mm, 3);
    }
    out << "\n";
  }
  return out ? Status::Ok() : Status::IoError("error writing " + path);
}

std::string GnuplotScript(const std::string& data, const std::string& png, const std::string& xlabel,
                          const std::vector<std::string>& methods) {
  std::string s = fmt::format(
      "set terminal pngcairo size 1000,600\nset output '{}'\nset xlabel '{}'\nset ylabel 'RMS (paper metric), mm'\n"
      "set y2label 'ADD median (ground truth), mm'\nset y2tics\nset ytics nomirror\nset logscale y\nset logscale y2\n"
      "set key outside right\nset grid\nset datafile missing '-'\nplot ",
      png, xlabel);
  for (std::size_t i = 0; i < methods.size(); ++i) {
    const std::size_t c = 2 + 4 * i;
    s += fmt::format("'{0}' using 1:{1}:{2}:{3} with yerrorlines title '{4} RMS mean (min-max)', "
                     "'{0}' using 1:{5} axes x1y2 with linespoints dt 2 title '{4} ADD median'{6}",
                     data, c, c + 1, c + 2, methods[i], c + 3, i + 1 < methods.size() ? ", " : "\n");
  }
  return s;
}

// Writes the data and script, then runs gnuplot if it is installed; returns a note for the report.
std::string Plot(const std::string& dir, const std::string& name, const std::string& xlabel, const Tables& tables,
                 const std::vector<std::string>& methods, const std::string& perturbation,
                 const std::function<double(const Run&)>& x) {
  const std::string data = dir + "/" + name + ".dat", script = dir + "/" + name + ".gp", png = dir + "/" + name + ".png";
  if (auto st = PlotData(data, tables.runs, methods, perturbation, x); !st.ok()) return st.ToString();
  std::ofstream(script) << GnuplotScript(data, png, xlabel, methods);
  if (std::system("command -v gnuplot >/dev/null 2>&1") != 0)
    return fmt::format("gnuplot is not installed: {} not drawn (data in {}, script {}; apt-get install gnuplot-nox)", png,
                       data, script);
  if (std::system(("gnuplot '" + script + "' 2>/dev/null").c_str()) != 0)
    return fmt::format("gnuplot failed on {}: {} not drawn", script, png);
  return fmt::format("![{}]({}.png)", name, name);
}

// Median time of every stage (and of the method's own steps, "register/...") per scenes-experiment
// method: where a request's time goes. A stage that did not run in a request counts as 0 ms.
void ProfileTable(std::ostream& md, const Tables& tables, const std::vector<std::string>& methods) {
  std::vector<std::string> stages;
  for (const auto& r : tables.runs)
    if (r.experiment == "scenes")
      for (const auto& [stage, ms] : r.stage_ms)
        if (std::find(stages.begin(), stages.end(), stage) == stages.end()) stages.push_back(stage);
  std::sort(stages.begin(), stages.end());
  md << "| method | runs |";
  for (const auto& s : stages) md << " " << s << " |";
  md << " total |\n|---|---|";
  for (std::size_t i = 0; i <= stages.size(); ++i) md << "---|";
  md << "\n";
  for (const auto& method : methods) {
    std::map<std::string, std::vector<double>> times;
    std::size_t n = 0;
    for (const auto& r : tables.runs) {
      if (r.experiment != "scenes" || r.method != method || !r.ok) continue;
      ++n;
      for (const auto& s : stages) times[s].push_back(r.stage_ms.count(s) ? r.stage_ms.at(s) : 0.0);
      times["total"].push_back(r.total_ms);
    }
    md << "| " << method << " | " << n << " |";
    for (const auto& s : stages) md << " " << Num(Median(times[s]), 1) << " |";
    md << " " << Num(Median(times["total"]), 1) << " |\n";
  }
  md << "\n";
}

const std::vector<std::string> kRobustnessLabels = {"method", "split", "robot", "mesher", "seeds", "voxel"};

Status WriteRobustness(const std::string& dir, const Tables& tables, const std::string& command_line) {
  ARREF_RETURN_IF_ERROR(CsvTable(dir + "/robustness.csv", tables.robustness, kRobustnessLabels, RobustnessColumns()));
  std::ofstream md(dir + "/robustness.md");
  if (!md) return Status::IoError("cannot write " + dir + "/robustness.md");
  md << "# arref bench: robustness\n\nCommand: `" << command_line << "`\n\n";
  md << "Robots x meshers x seed families, each run in the small configuration (2 m crop, 16,000 scene samples). "
        "Meshers: `own` is arref's TSDF and surface nets (which arref-icp also uses to predict the headset's mesh), "
        "`open3d` Open3D's TSDF, marching cubes and decimation with a device's variations drawn per cell. Seeds: "
        "`user` 0.1-0.3 m off horizontally and +-0.3 m in height round the base, ~15 deg yaw; `cube` uniform in "
        "+-0.5 m in x, y and z; `any-yaw` as user with any yaw. Success = ADD <= 10 mm over all runs (errors "
        "count as failures); wrong OK = said OK with ADD > 20 mm. Mesh error: the ADD of the gravity-aligned "
        "rigid motion that best explains where the headset's own errors (each view's tracking error as the fusion "
        "averages it, and open3d's per-surface head-pose errors) put the robot's seen surface in the mesh, which no "
        "fit against the true pose can be expected to beat. Voxel: the rows per mesher and voxel band "
        "(the voxel each cell's mesh was fused at; open3d draws 2-6 cm per cell).\n\n";
  MarkdownTable(md, tables.robustness, kRobustnessLabels, RobustnessColumns());
  for (const auto& n : tables.notes)
    if (n.rfind("robot: ", 0) != 0) md << "- " << n << "\n";  // --robot is the other experiments' robot
  if (!md) return Status::IoError("error writing " + dir + "/robustness.md");
  return Status::Ok();
}

}  // namespace

Status WriteReport(const Config& config, const Tables& tables, const std::string& command_line) {
  const std::string& dir = config.out_dir;
  ARREF_RETURN_IF_ERROR(RunsCsv(dir + "/runs.csv", tables.runs));
  ARREF_RETURN_IF_ERROR(CsvTable(dir + "/table1.csv", tables.table1, {"method", "size"}));
  ARREF_RETURN_IF_ERROR(CsvTable(dir + "/table2.csv", tables.table2, {"method", "size", "rank", "params"}));
  ARREF_RETURN_IF_ERROR(CsvTable(dir + "/table3.csv", tables.table3, {"method", "set"}));
  ARREF_RETURN_IF_ERROR(CsvTable(dir + "/scenes.csv", tables.scenes, {"method", "scene"}));
  std::vector<std::string> plotted = {"user guess"};
  plotted.insert(plotted.end(), config.perturb_methods.begin(), config.perturb_methods.end());
  // The figures show the seed perturbations (Table III); without that experiment there is nothing to draw.
  const bool perturbed = !tables.table3.empty();
  const std::string rotation_plot =
      perturbed ? Plot(dir, "rotation", "seed rotated about z, deg", tables, plotted, "rotation",
                       [](const Run& r) { return r.seed_yaw_deg; })
                : "(no figure: the perturbation experiment did not run)";
  const std::string translation_plot =
      perturbed ? Plot(dir, "translation", "seed moved along x, y or z, m", tables, plotted, "translation",
                       [](const Run& r) { return std::round(r.seed_offset_m.sum() * 10) / 10; })
                : "(no figure: the perturbation experiment did not run)";

  std::ofstream md(dir + "/results.md");
  if (!md) return Status::IoError("cannot write " + dir + "/results.md");
  md << "# arref bench\n\nCommand: `" << command_line << "`\n\n";
  md << "RMS is the paper's metric (all model points to the nearest scene point, mm); ADD, translation and rotation "
        "errors are against the simulator's ground truth; success = ADD <= 10 mm over all runs (errors count as "
        "failures); times are medians per run.\n\n";
  md << "## Table I: the parameter sweep, per algorithm and size\n\n";
  MarkdownTable(md, tables.table1, {"method", "size"});
  md << "## Table II: best and worst parameter sets\n\n";
  MarkdownTable(md, tables.table2, {"method", "size", "rank", "params"});
  md << "## Table III: twelve user guesses, rotated in 18 degree steps and moved along a 1 m cube in 0.1 m steps\n\n";
  MarkdownTable(md, tables.table3, {"method", "set"});
  md << rotation_plot << "\n\n" << translation_plot << "\n\n";
  md << "## Every method on each kind of scene (default parameters, user-like seeds)\n\n";
  MarkdownTable(md, tables.scenes, {"method", "scene"});
  if (!tables.scenes.empty()) {
    md << "### Where the time goes: median ms per stage (scenes experiment)\n\n";
    ProfileTable(md, tables, config.scene_methods);
  }
  for (const auto& n : tables.notes) md << "- " << n << "\n";
  if (!md) return Status::IoError("error writing " + dir + "/results.md");
  if (!tables.robustness.empty()) ARREF_RETURN_IF_ERROR(WriteRobustness(dir, tables, command_line));
  spdlog::info("bench: wrote {}/results.md, runs.csv, table*.csv, scenes.csv and plots", dir);
  return Status::Ok();
}

}  // namespace arref::bench
