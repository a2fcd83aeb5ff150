// `arref register`: register a robot model to a mesh file, optionally scored against truth.
#include <spdlog/spdlog.h>

#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>

#include "arref/scene/metrics.h"
#include "arref/pipeline/pipeline.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/pipeline/seedless.h"
#include "cli_common.h"
#include "commands.h"
#include "global_options.h"
#include "result_image.h"

namespace arref::cli {
namespace {

struct RegisterArgs {
  RobotArgs robot;
  std::string scene;
  std::string seed;
  int seed_index = 0;
  std::string frame = "ros";
  std::string truth;
  std::string head_path;
  std::string method = MethodName(RegistrationOptions{}.method);
  RegistrationOptions options;
  double mls_radius = 0;
  std::string mls_upsampling = "none";
  double mls_upsampling_radius = 0.01;
  double mls_upsampling_step = 0.005;
  int mls_order = 2;
  bool json = false;
  std::string image;         // PNG of the result
  int image_width = 1280;    // both views side by side, each 4:3
  std::string export_robot;  // the posed robot in the scene's frame
  bool whole_map = false;
};

struct Inputs {
  std::optional<nlohmann::json> truth;
  JointValues joints;
  Iso3 T_world_seed;
  bool seedless = false;  // no seed anywhere (or --whole-map): the whole map is searched
  Iso3 T_world_base_true;
  std::vector<Vec3> head_path_world;
};

// A JSON file's "head_path" in its "frame" (`arref simulate`'s truth file has both).
Result<std::vector<Vec3>> ReadHeadPath(const std::string& file) {
  ARREF_ASSIGN_OR_RETURN(const nlohmann::json j, ReadJsonFile(file));
  if (!j.contains("head_path")) return Status::InvalidArgument("no \"head_path\" in the file");
  ARREF_ASSIGN_OR_RETURN(const FrameConvention frame, FrameOfFile(j));
  auto path = PositionsFromJson(j["head_path"], frame);
  if (!path.ok()) return path.status().WithContext("head_path");
  return path;
}

Result<Inputs> ReadInputs(const RegisterArgs& args, FrameConvention frame) {
  Inputs in;
  if (!args.truth.empty()) {
    auto truth = ReadJsonFile(args.truth);
    if (!truth.ok()) return truth.status().WithContext("--truth");
    in.truth = std::move(*truth);
    auto T = MatrixFromJson(in.truth->value("T_world_base", nlohmann::json()));
    if (!T.ok()) return T.status().WithContext("--truth " + args.truth + ": T_world_base");
    in.T_world_base_true = *T;
  }
  ARREF_ASSIGN_OR_RETURN(in.joints, ParseJoints(args.robot.joints));
  if (args.robot.joints.empty() && in.truth && in.truth->contains("joints")) {  // the scene's own robot pose
    auto truth_joints = JointsFromJson((*in.truth)["joints"]);
    if (!truth_joints.ok()) return truth_joints.status().WithContext("--truth " + args.truth);
    in.joints = *truth_joints;
  }

  if (args.whole_map) {
    in.seedless = true;
  } else if (!args.seed.empty()) {
    auto seed = ParsePose(args.seed, frame);
    if (!seed.ok()) return seed.status().WithContext("--seed");
    in.T_world_seed = *seed;
  } else if (in.truth && in.truth->contains("seeds")) {
    const auto& seeds = (*in.truth)["seeds"];
    if (args.seed_index < 0 || args.seed_index >= static_cast<int>(seeds.size()))
      return Status::InvalidArgument("--seed-index " + std::to_string(args.seed_index) + ": the truth file has " +
                                     std::to_string(seeds.size()) + " seeds");
    auto truth_frame = FrameOfFile(*in.truth);
    if (!truth_frame.ok()) return truth_frame.status().WithContext("--truth frame");
    auto seed = PoseFromJson(seeds[args.seed_index], *truth_frame);
    if (!seed.ok()) return seed.status().WithContext("--truth seeds[" + std::to_string(args.seed_index) + "]");
    in.T_world_seed = *seed;
  } else {
    in.seedless = true;  // no seed: the whole map is searched
  }
  if (!args.head_path.empty()) {
    auto path = ReadHeadPath(args.head_path);
    if (!path.ok()) return path.status().WithContext("--head-path " + args.head_path);
    in.head_path_world = std::move(*path);
  }
  return in;
}

nlohmann::json ReportJson(const RegistrationReport& r, FrameConvention frame) {
  nlohmann::json j;
  j["status"] = ResultStatusName(r.status);
  if (!r.status_reason.empty()) j["status_reason"] = r.status_reason;
  j["method"] = r.method;
  j["stages_run"] = r.stages_run;
  j["T_world_base"] = MatrixToJson(r.T_world_base);
  const nlohmann::json pose = PoseToJson(r.T_world_base, frame);
  j["frame"] = FrameConventionName(frame);
  j["position"] = {pose[0], pose[1], pose[2]};
  j["orientation"] = {pose[3], pose[4], pose[5], pose[6]};
  j["rms_m"] = r.rms_m;
  j["rms_points"] = r.rms_points;
  if (r.score >= 0) j["score"] = r.score;
  if (r.margin >= 0) j["margin"] = r.margin;
  if (r.hypotheses > 0) j["hypotheses"] = r.hypotheses;
  j["inlier_fraction"] = r.inlier_fraction;
  if (r.precision.valid)
    j["expected_error_m"] = {{"total", r.precision.expected_error_m}, {"fit", r.precision.fit_error_m},
                             {"map", r.precision.map_error_m}, {"surface", r.precision.surface_error_m},
                             {"surface_misfit", r.precision.surface_misfit_m}};
  j["iterations"] = r.iterations;
  j["converged"] = r.converged;
  j["points"] = {{"scene_triangles", r.scene_triangles}, {"scene", r.scene_points}, {"model", r.model_points}};
  nlohmann::json timings;
  for (const auto& t : r.timings) timings[t.stage] = t.ms;
  timings["total"] = r.total_ms();
  j["timings_ms"] = timings;
  if (!r.method_steps.empty()) {
    nlohmann::json steps;  // inside the "register" stage
    for (const auto& t : r.method_steps) steps[t.stage] = t.ms;
    j["method_steps_ms"] = steps;
  }
  return j;
}

void PrintHuman(const nlohmann::json& j) {
  const auto& T = j["T_world_base"];
  std::printf("T_world_base (internal frame, row-major):\n");
  for (int r = 0; r < 4; ++r)
    std::printf("  % .5f % .5f % .5f % .5f\n", T[4 * r].get<double>(), T[4 * r + 1].get<double>(),
                T[4 * r + 2].get<double>(), T[4 * r + 3].get<double>());
  std::printf("status %s\n", j["status"].get<std::string>().c_str());
  std::printf("rms %.2f mm (%s model points), inliers %.1f %%, %d iterations, %.0f ms\n", j["rms_m"].get<double>() * 1e3,
              j["rms_points"].get<std::string>().c_str(),
              j["inlier_fraction"].get<double>() * 100, j["iterations"].get<int>(), j["timings_ms"]["total"].get<double>());
  if (const auto e = j.find("expected_error_m"); e != j.end())
    std::printf("%s\n", ExpectedErrorLine((*e)["total"].get<double>(), (*e)["fit"].get<double>(), (*e)["map"].get<double>(),
                                          (*e)["surface"].get<double>()).c_str());
  if (j.contains("add_m"))
    std::printf("vs truth: ADD %.2f mm, translation %.2f mm, rotation %.2f deg\n", j["add_m"].get<double>() * 1e3,
                j["translation_error_m"].get<double>() * 1e3, j["rotation_error_deg"].get<double>());
}

// --image and --export-robot: the posed robot at the result, drawn over the scene or written out.
Status WriteResultFiles(const RegisterArgs& args, const RobotModel& robot, const JointValues& joints,
                        const TriangleMesh& scene_world, const RegistrationReport& report, const Iso3& T_world_seed,
                        FrameConvention frame) {
  if (args.image.empty() && args.export_robot.empty()) return Status::Ok();
  ARREF_ASSIGN_OR_RETURN(const JointValues complete, robot.CompleteJoints(joints));
  ARREF_ASSIGN_OR_RETURN(TriangleMesh posed, robot.PosedMesh(complete));
  if (!args.image.empty()) {
    const ResultPicture picture{.scene_world = scene_world, .robot_base = posed, .T_world_base = report.T_world_base,
                                .T_world_seed = T_world_seed};
    const int view_width = args.image_width / 2;
    auto image = RenderResult(picture, ResultImageOptions{.view_width = view_width, .view_height = view_width * 3 / 4,
                                                          .crop_radius_m = args.options.crop_radius_m});
    if (!image.ok()) return image.status().WithContext("--image");
    ARREF_RETURN_IF_ERROR(WritePng(*image, args.image));
    spdlog::info("wrote {} ({} x {} px)", args.image, image->width, image->height);
  }
  if (!args.export_robot.empty()) {
    posed.Transform(report.T_world_base);
    MeshFromRos(posed, frame);  // the scene file's own convention
    if (Status s = SaveMeshFile(posed, args.export_robot); !s.ok()) return s.WithContext("--export-robot");
    spdlog::info("wrote the posed robot to {} ({} frame)", args.export_robot, FrameConventionName(frame));
  }
  return Status::Ok();
}

ProgressFn TerminalProgress() {
  if (!StderrIsTerminal()) return {};
  return [](std::string_view stage, double fraction) {
    std::fprintf(stderr, "\r%-10.*s %3.0f %%%s", static_cast<int>(stage.size()), stage.data(), fraction * 100,
                 fraction >= 1.0 ? "\n" : "");
  };
}

// No seed: the whole map is searched (arref-auto unless a seedless method is named); the primary
// instance's report, and every instance found under "candidates".
// The result's error against the truth file's pose, in the printed result.
void AddTruthError(const Iso3& T_world_base, const Iso3& T_world_base_true, const RobotSide& model, nlohmann::json* j) {
  const PoseError e = ComparePoses(T_world_base, T_world_base_true, model.samples().points);
  (*j)["translation_error_m"] = e.translation_m;
  (*j)["rotation_error_deg"] = e.rotation_deg;
  (*j)["add_m"] = e.add_m;
}

int PrintResult(const RegisterArgs& args, const nlohmann::json& j, ResultStatus status) {
  if (args.json)
    std::cout << j.dump(2) << std::endl;
  else
    PrintHuman(j);
  return status == ResultStatus::kFailed ? kExitRegistrationFailed : kExitOk;
}

int RunWholeMap(const RegisterArgs& args, const Inputs& inputs, const RobotSide& model, const TriangleMesh& scene,
                RegistrationOptions options, FrameConvention frame) {
  const MethodInfo* info = FindMethod(options.method);
  if (!info || !info->seedless) {
    if (args.method != MethodName(RegistrationOptions{}.method))
      return Fail(Status::InvalidArgument(fmt::format(
          "no seed: method '{}' needs one; pass --seed x,y,z,qx,qy,qz,qw, a --truth file with seeds, or a seedless "
          "--method (arref-auto, sliding-box-shot)", args.method)));
    options.method = Method::kArrefAuto;
  }
  auto whole = RegisterWholeMap(model, scene, options, {}, TerminalProgress());
  if (!whole.ok()) return Fail(whole.status());
  nlohmann::json j;
  if (whole->primary >= 0) j = ReportJson(whole->instances[static_cast<std::size_t>(whole->primary)].report, frame);
  j["status"] = ResultStatusName(whole->status);
  if (!whole->status_reason.empty()) j["status_reason"] = whole->status_reason;
  j["method"] = whole->method;
  j["candidates_tried"] = whole->candidates;
  j["whole_map_stages"] = whole->stages_run;
  nlohmann::json timings;
  for (const auto& t : whole->timings) timings[t.stage] = t.ms;
  timings["total"] = whole->total_ms();
  j["whole_map_timings_ms"] = timings;
  j["candidates"] = nlohmann::json::array();
  for (const FoundInstance& f : whole->instances) {
    nlohmann::json c = ReportJson(f.report, frame);
    nlohmann::json entry = {{"status", c["status"]}, {"position", c["position"]}, {"orientation", c["orientation"]},
                            {"T_world_base", c["T_world_base"]}, {"inlier_fraction", c["inlier_fraction"]}};
    for (const char* key : {"score", "margin", "status_reason"})
      if (c.contains(key)) entry[key] = c[key];
    if (inputs.truth) entry["add_m"] = ComparePoses(f.report.T_world_base, inputs.T_world_base_true, model.samples().points).add_m;
    j["candidates"].push_back(entry);
  }
  if (inputs.truth && whole->primary >= 0)
    AddTruthError(whole->instances[static_cast<std::size_t>(whole->primary)].report.T_world_base, inputs.T_world_base_true,
                  model, &j);
  return PrintResult(args, j, whole->status);
}

int Run(const RegisterArgs& args) {
  auto frame = ParseFrameConvention(args.frame);
  if (!frame.ok()) return Fail(frame.status());
  auto method = ParseMethod(args.method);
  if (!method.ok()) return Fail(method.status());
  RegistrationOptions options = args.options;
  options.method = *method;
  if (args.mls_radius > 0) {
    auto upsampling = ParseMlsUpsampling(args.mls_upsampling);
    if (!upsampling.ok()) return Fail(upsampling.status());
    options.mls = MlsOptions{.search_radius_m = args.mls_radius, .polynomial_order = args.mls_order,
                             .upsampling = *upsampling, .upsampling_radius_m = args.mls_upsampling_radius,
                             .upsampling_step_m = args.mls_upsampling_step};
  }
  auto inputs = ReadInputs(args, *frame);
  if (!inputs.ok()) return Fail(inputs.status());
  auto robot = LoadRobot(args.robot);
  if (!robot.ok()) return Fail(robot.status());
  auto model = RobotSide::Create(*robot, inputs->joints, options.model_samples, options.sample_seed);
  if (!model.ok()) return Fail(model.status());
  auto scene = LoadMeshFile(args.scene);
  if (!scene.ok()) return Fail(scene.status().WithContext("--scene"));
  MeshToRos(*scene, *frame);

  options.head_path_world = inputs->head_path_world;
  const MethodInfo* info = FindMethod(options.method);
  if (inputs->seedless || (info && info->seedless)) return RunWholeMap(args, *inputs, **model, *scene, options, *frame);
  auto report = RegisterScene(**model, *scene, inputs->T_world_seed, options, TerminalProgress());
  if (!report.ok()) return Fail(report.status());
  if (Status s = WriteResultFiles(args, *robot, inputs->joints, *scene, *report, inputs->T_world_seed, *frame); !s.ok())
    return Fail(s);
  nlohmann::json j = ReportJson(*report, *frame);
  if (inputs->truth) AddTruthError(report->T_world_base, inputs->T_world_base_true, **model, &j);
  return PrintResult(args, j, report->status);
}

std::string MethodHelp() {
  std::string help = "Registration method:";
  for (const auto& m : Methods()) help += std::string("\n  ") + m.name + ": " + m.description;
  return help;
}

}  // namespace

void AddRegisterCommand(CLI::App& app, int* exit_code) {
  auto args = std::make_shared<RegisterArgs>();
  CLI::App* cmd = app.add_subcommand("register", "Register a robot model to a headset mesh");
  AddRobotOptions(*cmd, args->robot);
  cmd->add_option("--scene", args->scene, "Headset mesh (PLY, OBJ or STL)")->required();
  cmd->add_option("--seed", args->seed,
                  "Seed pose x,y,z,qx,qy,qz,qw (default: a seed from --truth; with neither, the whole map is searched)");
  cmd->add_flag("--whole-map", args->whole_map,
                "Search the whole map with no seed (arref-auto, or a seedless --method), even with --truth seeds");
  cmd->add_option("--seed-index", args->seed_index, "Which of the truth file's seeds to use")->capture_default_str();
  cmd->add_option("--frame", args->frame, "Convention of seed, mesh and output: ros or unity")
      ->check(CLI::IsMember({"ros", "unity"}))->capture_default_str();
  cmd->add_option("--truth", args->truth, "Ground truth JSON (from arref simulate): adds the true error");
  cmd->add_option("--head-path", args->head_path,
                  "JSON file whose \"head_path\" ([[x,y,z], ...] in its \"frame\") is where the headset was while "
                  "mapping, e.g. arref simulate's truth file: arref-icp models the mesh from those eyes");
  cmd->add_option("--method", args->method, MethodHelp())->capture_default_str();
  RegistrationOptions& o = args->options;
  cmd->add_option("--crop-radius", o.crop_radius_m, "Crop the scene to this radius around the seed, m")->capture_default_str();
  cmd->add_option("--samples", o.scene_samples, "Scene surface samples")->capture_default_str();
  cmd->add_option("--model-samples", o.model_samples, "Robot surface samples")->capture_default_str();
  cmd->add_option("--voxel", o.voxel_leaf_m, "Voxel downsampling leaf for the scene sample, m (0: off)");
  cmd->add_option("--max-correspondence", o.icp.max_correspondence_m, "ICP max correspondence distance, m")->capture_default_str();
  cmd->add_option("--max-iterations", o.icp.max_iterations, "ICP max iterations")->capture_default_str();
  cmd->add_option("--transformation-epsilon", o.icp.transformation_epsilon, "ICP transformation epsilon");
  cmd->add_option("--fitness-epsilon", o.icp.euclidean_fitness_epsilon, "ICP Euclidean fitness epsilon");
  cmd->add_option("--inlier-threshold", o.inlier_threshold_m, "Distance counted as inlier, m")->capture_default_str();
  cmd->add_flag("--expected-surface,!--exact-surface", o.arref_icp.expected_surface,
                "arref-icp: fit the exact robot surface (visible parts) instead of the robot as the headset would mesh it")
      ->default_str("expected");
  cmd->add_flag("--context,!--no-context", o.arref_icp.in_context,
                "arref-icp: skip the refit with the objects mapped round the robot (faster; a table near the robot then "
                "pulls the fit a few mm)")
      ->default_str("context");
  cmd->add_option("--tracking-error", o.arref_icp.tracking_error.position_m,
                  "arref-icp: the headset's head-position error per view (sigma per axis), m; its last polish weighs "
                  "each point by how far the tracking error moves the mesh there (0: equal weights)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  cmd->add_option("--tracking-error-deg", o.arref_icp.tracking_error.orientation_deg,
                  "arref-icp: the headset's head-orientation error per view (sigma per axis), degrees")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 30.0));
  cmd->add_option("--expected-voxel", o.arref_icp.expected_voxel_m,
                  "arref-icp: voxel of the headset mesh, m (default: the cropped mesh's median edge length)");
  cmd->add_option("--sample-seed", o.sample_seed, "Seed of the surface sampling")->capture_default_str();
  cmd->add_option("--mls", args->mls_radius, "Moving Least Squares search radius, m (0: off)");
  cmd->add_option("--mls-order", args->mls_order, "MLS polynomial order");
  cmd->add_option("--mls-upsampling", args->mls_upsampling,
                  "none, sample-local-plane, random-uniform-density, voxel-grid-dilation");
  cmd->add_option("--mls-upsampling-radius", args->mls_upsampling_radius, "MLS upsampling radius, m");
  cmd->add_option("--mls-upsampling-step", args->mls_upsampling_step, "MLS upsampling step, m");
  AddGlobalMethodOptions(*cmd, o);
  cmd->add_flag("--json", args->json, "Print the result as JSON on stdout");
  cmd->add_option("--image", args->image,
                  "Write a PNG of the result: the cropped scene and the registered robot (orange) from the front and "
                  "from above, the seed cube (magenta), the scene coloured by distance to the robot");
  cmd->add_option("--image-width", args->image_width, "Width of the --image in pixels (two 4:3 views side by side)")
      ->capture_default_str()
      ->check(CLI::Range(64, 8192));
  cmd->add_option("--export-robot", args->export_robot,
                  "Write the posed robot at the result in the scene's frame (.ply, .stl or .obj), for MeshLab or Blender");
  cmd->callback([args, exit_code] { *exit_code = Run(*args); });
}

}  // namespace arref::cli
