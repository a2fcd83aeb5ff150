#include "arref/pipeline/pipeline.h"

#include <spdlog/spdlog.h>
#include <tbb/task_group.h>

#include <algorithm>

#include "arref/base/clock.h"
#include "arref/fusion/robot_side.h"
#include "arref/icp/fast_icp.h"
#ifdef ARREF_WITH_PCL
#include "arref/baselines/baselines.h"
#endif
#include "arref/scene/metrics.h"
#include "arref/scene/sampling.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/fusion/model_visibility.h"
#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/spatial_mesh.h"

namespace arref {
namespace {

class StageClock {
 public:
  StageClock(std::vector<StageTime>* out, const ProgressFn& progress) : out_(out), progress_(progress) {}
  // Ends the running stage (if any) and starts the next.
  void Start(std::string stage, double fraction) {
    Stop();
    stage_ = std::move(stage);
    laps_.Restart();
    if (progress_) progress_(stage_, fraction);
  }
  void Stop() {
    if (stage_.empty()) return;
    const double ms = laps_.Lap();
    out_->push_back({stage_, ms});
    spdlog::debug("stage {}: {:.1f} ms", stage_, ms);
    stage_.clear();
  }

 private:
  std::vector<StageTime>* out_;
  const ProgressFn& progress_;
  std::string stage_;
  LapTimer laps_;
};

// Waits for a task group's tasks when it goes out of scope, so that none outlives what it uses.
// Only an early return leaves them unwaited, and its error is the one reported: a task's own
// exception is dropped there rather than thrown from a destructor.
struct WaitOnExit {
  tbb::task_group& group;
  ~WaitOnExit() {
    try {
      group.wait();
    } catch (...) {
    }
  }
};

Status CheckOptions(const RegistrationOptions& o) {
  if (!(o.crop_radius_m > 0)) return Status::InvalidArgument("crop radius must be > 0 m");
  if (o.scene_samples < 3) return Status::InvalidArgument("scene samples must be >= 3");
  if (o.voxel_leaf_m < 0) return Status::InvalidArgument("voxel leaf must be >= 0 m");
  if (!(o.inlier_threshold_m > 0)) return Status::InvalidArgument("inlier threshold must be > 0 m");
  return Status::Ok();
}

// Polled between the pipeline's stages; inside them the method and the expected surfaces poll
// the token themselves (arref_icp.cpp, model_reconstruction.cpp).
Status CheckCancel(const CancelToken* cancel, const char* before) {
  if (Cancelled(cancel)) return Status::Cancelled(fmt::format("registration cancelled before {}", before));
  return Status::Ok();
}

// A mesh whose voxel is coarse for the robot's size: fewer than min_voxels_across_robot voxels
// span its largest bounding-box side, so its shell hides several millimetres of pose (a small arm
// meshed at 5 cm).
std::string CoarseMeshReason(const ConfidenceThresholds& t, const PointCloud& model_base, double voxel_m) {
  if (!(voxel_m > 0) || model_base.empty()) return {};
  Aabb box;
  for (const Vec3f& p : model_base.points) box.Extend(p);
  const double side = (box.max - box.min).maxCoeff();
  const double across = side / voxel_m;
  if (across >= t.min_voxels_across_robot) return {};
  return fmt::format("the mesh is coarse for this robot: its {:.1f} cm voxel spans the robot's {:.2f} m "
                     "only {:.0f} times (under {:.0f}), so the pose may be off by more than a centimetre",
                     voxel_m * 100, side, across, t.min_voxels_across_robot);
}

// A fit may stand in the right place and still be too imprecise for the product's promise: its
// map (head tracking's error per view, over the eyes that saw the robot), the disagreement of
// the robot's two surface models, or the kept model lying off the mesh can put it more than a
// centimetre off (docs/engine.md, steps 8 and 9); the reason names the last when there is one.
std::string ImpreciseReason(const ConfidenceThresholds& t, const FitPrecision& p) {
  if (!(t.ok_max_expected_error_m > 0) || !p.valid || p.expected_error_m <= t.ok_max_expected_error_m) return {};
  const std::string misfit =
      p.surface_misfit_m > 0
          ? fmt::format("; the robot's surface model lies {:.1f} mm off the mesh in median", p.surface_misfit_m * 1e3)
          : std::string();
  return fmt::format("the pose may be off by more than {:.0f} mm: its expected error is {:.1f} mm (the fit's {:.1f}, "
                     "the map's {:.1f}, the surface models' {:.1f}){}",
                     t.ok_max_expected_error_m * 1e3, p.expected_error_m * 1e3, p.fit_error_m * 1e3,
                     p.map_error_m * 1e3, p.surface_error_m * 1e3, misfit);
}

// not_as_posed: non-empty when the fit cannot stand for the robot as posed (a model of some of
// its links, or a map made while it moved): why it is not OK.
void AssignStatus(const ConfidenceThresholds& t, bool calibrated, const std::string& coarse_mesh,
                  const std::string& not_as_posed, RegistrationReport* r) {
  std::string why;
  if (r->inlier_fraction < t.ok_min_inlier_fraction)
    why = fmt::format("only {:.0f} % of visible model points lie on the scene", r->inlier_fraction * 100);
  else if (r->margin < 0)  // measured: PCL ICP 2-4 cm off keeps as many inliers as a good fit
    why = "the method does not compare alternative poses, so a nearby wrong fit cannot be ruled out";
  else if (!calibrated)  // measured: arref-icp-point 21 mm off passed the thresholds below
    why = "the confidence thresholds were not calibrated on this method's fits";
  else if (r->margin < t.ok_min_margin)
    why = fmt::format("ambiguous: another pose fits almost as well (margin {:.3f})", r->margin);
  else if (r->turned && r->turned->lead < t.ok_min_turned_lead)
    why = fmt::format("the yaw is uncertain: turned {:.0f} degrees about its base the robot fits almost as well "
                      "(lead {:.3f})", r->turned->turn_deg, r->turned->lead);
  else if (!coarse_mesh.empty())
    why = coarse_mesh;
  else if (!not_as_posed.empty())
    why = not_as_posed;
  r->imprecise_only = false;
  if (why.empty()) {
    why = ImpreciseReason(t, r->precision);
    r->imprecise_only = !why.empty();
  }
  r->status_reason = why;
  if (why.empty())
    r->status = ResultStatus::kOk;
  else
    r->status = r->inlier_fraction < t.failed_below_inlier_fraction ? ResultStatus::kFailed : ResultStatus::kLowConfidence;
}

// The fit's precision over at most kPrecisionPoints of the visible model (Thinned: the
// covariance needs the surface's spread, not every sample). The mesh's edge is the length over
// which its residuals are correlated.
FitPrecision Precision(const PointCloud& visible, const TargetCloud& target, const Iso3& T_world_base,
                       const RegistrationOutput& method, const RegistrationOptions& options, double edge_m) {
  constexpr std::size_t kPrecisionPoints = 4000;
  const PointCloud kept = Thinned(visible, kPrecisionPoints);
  return MeasurePrecision(kept.points, kept.normals, target, T_world_base, method.eyes_world,
                          method.has_other_surface ? &method.other_surface : nullptr,
                          PrecisionSettings{.max_distance_m = options.inlier_threshold_m,
                                            .correlation_m = edge_m,
                                            .view_error = options.arref_icp.tracking_error});
}

}  // namespace

double RegistrationReport::total_ms() const {
  double total = 0;
  for (const auto& t : timings) total += t.ms;
  return total;
}

const char* ResultStatusName(ResultStatus status) {
  switch (status) {
    case ResultStatus::kOk: return "OK";
    case ResultStatus::kLowConfidence: return "LOW_CONFIDENCE";
    case ResultStatus::kFailed: return "FAILED";
  }
  return "FAILED";
}

namespace {

// Below 2 cm a fused shell lies within a few millimetres of the surface: the exact surface fits
// as well or better, and the expected surfaces would take seconds to build (docs/engine.md,
// "Exact or expected surface"). Above 15 cm a mesh is
// too coarse for the fusion to say anything.
constexpr double kMinExpectedVoxel = 0.02, kMaxExpectedVoxel = 0.15;

// The robot as the headset meshes it, at the voxel of this scene; null when the mesh is too fine
// for it to matter or too coarse to model (then the exact surface is fitted).
Result<std::shared_ptr<const PointCloud>> ExpectedSurface(const RobotSide& robot, double voxel,
                                                          const CancelToken* cancel) {
  if (voxel < kMinExpectedVoxel) {
    spdlog::debug("scene mesh voxel {:.4f} m: fine enough to fit the exact robot surface", voxel);
    return std::shared_ptr<const PointCloud>();
  }
  if (voxel > kMaxExpectedVoxel) {
    spdlog::warn("scene mesh voxel {:.3f} m is coarser than {} m: fitting the exact robot surface", voxel,
                 kMaxExpectedVoxel);
    return std::shared_ptr<const PointCloud>();
  }
  return robot.Expected(voxel, -1, 0, cancel);
}

Result<RegistrationReport> Register(const PointCloud& model_base, const RobotSide* robot,
                                    const TriangleMesh& scene_world, const Iso3& T_world_seed,
                                    const RegistrationOptions& options, const ProgressFn& progress,
                                    const CancelToken* cancel) {
  ARREF_RETURN_IF_ERROR(CheckOptions(options));
  const MethodInfo* method = FindMethod(options.method);
  if (!method) return Status::InvalidArgument("registration method not built in (arref was built without ARREF_WITH_PCL)");
  if (!T_world_seed.matrix().allFinite()) return Status::InvalidArgument("seed pose is not finite");
  if (model_base.size() < 3) return Status::FailedPrecondition("robot model has fewer than 3 points");
  RegistrationReport report;
  report.T_world_seed = T_world_seed;
  report.method = method->name;
  StageClock clock(&report.timings, progress);

  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "the crop"));
  clock.Start("crop", 0.0);
  const TriangleMesh cropped = CropToSphere(scene_world, T_world_seed.translation(), options.crop_radius_m);
  report.scene_triangles = cropped.triangles.size();
  if (cropped.empty()) {
    const Vec3 c = T_world_seed.translation();
    return Status::FailedPrecondition(fmt::format(
        "no scene triangles within {} m of the seed at ({:.3f}, {:.3f}, {:.3f}); is the seed in the mesh's frame?",
        options.crop_radius_m, c.x(), c.y(), c.z()));
  }

  // The expected surface is looked up while the scene is sampled and indexed: the median edge
  // length it needs is about 1 ms of serial work (and the first request per voxel size builds
  // the surfaces). Its stage is the wait for it after the index.
  const bool wants_expected =
      robot && method->uses_expected_surface && options.arref_icp.expected_surface;
  double voxel = 0;
  Result<std::shared_ptr<const PointCloud>> expected = std::shared_ptr<const PointCloud>();
  tbb::task_group alongside;
  const WaitOnExit wait_on_exit{alongside};  // also on the early returns below
  if (wants_expected)
    alongside.run([&] {
      voxel = options.arref_icp.expected_voxel_m > 0 ? options.arref_icp.expected_voxel_m : MedianEdgeLength(cropped);
      expected = ExpectedSurface(*robot, voxel, cancel);
    });

  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "sampling"));
  clock.Start("sample", 0.1);
  PointCloud scene = SampleSurface(cropped, options.scene_samples, options.sample_seed);
  if (options.mls) {
    ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "MLS resampling"));
    clock.Start("mls", 0.2);
#ifdef ARREF_WITH_PCL
    auto resampled = MlsResample(scene, *options.mls);
    if (!resampled.ok()) return resampled.status().WithContext("MLS resampling");
    scene = std::move(resampled).value();
#else
    return Status::FailedPrecondition("MLS resampling needs arref built with ARREF_WITH_PCL");
#endif
    report.stages_run.push_back("mls");
  }
  if (options.voxel_leaf_m > 0) {
    clock.Start("voxel", 0.25);
    scene = VoxelDownsample(scene, options.voxel_leaf_m);
    report.stages_run.push_back("voxel");
  }
  report.scene_points = scene.size();
  report.model_points = model_base.size();

  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "indexing"));
  clock.Start("index", 0.28);
  // One k-d tree of the scene serves the method (when it takes one) and the evaluation.
  const TargetCloud target(scene);
  if (wants_expected) {
    clock.Start("expected-surface", 0.29);  // a cache hit after the first request per voxel size
    alongside.wait();
    if (!expected.ok()) return expected.status();  // a cancel while it was made included
    if (*expected) report.stages_run.insert(report.stages_run.begin(), "expected-surface");
  }
  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "the method"));
  clock.Start("register", 0.3);
  auto out = method->run(MethodInput{.model_base = model_base,
                                     .scene_world = scene,
                                     .scene_target = target,
                                     .T_world_seed = T_world_seed,
                                     .options = options,
                                     .robot = robot,
                                     .model_expected = *expected,
                                     .voxel_m = voxel,
                                     .scene_mesh_world = &cropped,
                                     .cancel = cancel});
  if (!out.ok()) return out.status().WithContext(report.method);
  report.T_world_base = out->T_world_base;
  report.iterations = out->iterations;
  report.converged = out->converged;
  report.score = out->score;
  report.margin = out->margin;
  report.turned = out->turned;
  report.hypotheses = out->hypotheses;
  for (const auto& [step, ms] : out->step_ms) report.method_steps.push_back({step, ms});
  report.stages_run.insert(report.stages_run.end(), out->stages.begin(), out->stages.end());

  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "the evaluation"));
  clock.Start("evaluate", 0.9);
  const PointIndex& scene_index = target.index();
  const bool visible_only = method->visible_model_only && model_base.has_visibility();
  report.rms_points = visible_only ? "visible" : "all";
  const PointCloud visible_model = VisiblePoints(model_base);
  const std::vector<Vec3f>& visible = visible_model.points;
  // RMS over the points the method fits (the paper's metric for the paper's methods).
  const FitQuality fit = MeasureFit(visible_only ? visible : model_base.points, report.T_world_base, scene_index,
                                    options.inlier_threshold_m);
  report.rms_m = fit.rms_m;
  // Confidence rests on the visible points whatever the method, so that statuses compare.
  report.inlier_fraction = visible_only ? fit.inlier_fraction
                                        : MeasureFit(visible, report.T_world_base, scene_index,
                                                     options.inlier_threshold_m).inlier_fraction;
  // Where the exact surface explained the scene better than a fused shell (exact geometry, a fine
  // scan), the mesh's edge length is no voxel and says nothing of its accuracy.
  const bool fused = std::find(report.stages_run.begin(), report.stages_run.end(), "fitted-exact-surface") ==
                     report.stages_run.end();
  const double edge = voxel > 0 ? voxel : MedianEdgeLength(cropped);
  const double mesh_voxel = fused ? edge : 0.0;
  report.precision = Precision(visible_model, target, report.T_world_base, *out, options, edge);
  // A fit on a map that does not show the robot as posed, or on part of the robot, is never OK:
  // on smeared maps both were said OK 20-62 mm off, and on part of a small arm up to 0.75 m
  // (docs/robustness.md, "Joints moving while the map is made").
  const std::string not_as_posed =
      robot && robot->partial() ? "the fit rests on the links that stood still while the map was made, not the whole robot"
                                : options.map_not_as_posed;
  AssignStatus(options.confidence, method->status_calibrated, CoarseMeshReason(options.confidence, model_base, mesh_voxel),
               not_as_posed, &report);
  clock.Stop();
  if (progress) progress("done", 1.0);
  return report;
}

}  // namespace

Result<RegistrationReport> RegisterScene(const RobotSide& robot, const TriangleMesh& scene_world,
                                         const Iso3& T_world_seed, const RegistrationOptions& options,
                                         const ProgressFn& progress, const CancelToken* cancel) {
  return Register(robot.samples(), &robot, scene_world, T_world_seed, options, progress, cancel);
}

Result<RegistrationReport> RegisterScene(const PointCloud& model_base, const TriangleMesh& scene_world,
                                         const Iso3& T_world_seed, const RegistrationOptions& options,
                                         const ProgressFn& progress, const CancelToken* cancel) {
  return Register(model_base, nullptr, scene_world, T_world_seed, options, progress, cancel);
}

}  // namespace arref
