// Global method + ICP refinement: the paper's Super4PCS path (Puljiz et al. 2019, Sec. IV-B)
// generalised to any global aligner.
#include <spdlog/spdlog.h>

#include "global_registration.h"
#include "arref/base/clock.h"

namespace arref {

namespace {

Result<GlobalAlignment> Align(GlobalAligner aligner, const PointCloud& model_base, const PointCloud& scene,
                              const GlobalParams& params) {
  switch (aligner) {
    case GlobalAligner::kSuper4pcs: return AlignSuper4pcs(model_base, scene, params.super4pcs);
    case GlobalAligner::kPcl4pcs: return AlignPcl4pcs(model_base, scene, params.pcl_4pcs, false);
    case GlobalAligner::kPclK4pcs: return AlignPcl4pcs(model_base, scene, params.pcl_4pcs, true);
    case GlobalAligner::kFpfhRansac: return AlignFpfhRansac(model_base, scene, params.fpfh_ransac);
  }
  return Status::InvalidArgument("unknown global aligner");
}

const char* NameOf(GlobalAligner aligner) {
  switch (aligner) {
    case GlobalAligner::kSuper4pcs: return "super4pcs";
    case GlobalAligner::kPcl4pcs: return "pcl-4pcs";
    case GlobalAligner::kPclK4pcs: return "pcl-k4pcs";
    case GlobalAligner::kFpfhRansac: return "fpfh-ransac";
  }
  return "global";
}

}  // namespace

Result<RegistrationOutput> RegisterGlobalThenIcp(GlobalAligner aligner, const PointCloud& model_base,
                                                 const PointCloud& scene_world, const Iso3& T_world_seed,
                                                 const GlobalParams& params) {
  const char* name = NameOf(aligner);
  RegistrationOutput out;
  LapTimer laps;  // each step's time goes to out.step_ms
  PointCloud segmented;
  const PointCloud* scene = &scene_world;
  if (params.segmentation.enabled) {
    auto seg = SegmentNearSeed(scene_world, T_world_seed, model_base, params.segmentation);
    if (!seg.ok()) return seg.status();
    segmented = std::move(*seg);
    scene = &segmented;
    out.stages.push_back("segment");
    out.step_ms.emplace_back("segmentation", laps.Lap());
  }
  auto global = Align(aligner, model_base, *scene, params);
  if (!global.ok()) return global.status();  // the pipeline prefixes the method's name
  out.stages.push_back(name);
  out.step_ms.emplace_back("global-alignment", laps.Lap());
  spdlog::debug("{}: score {:.3f} after {} iterations", name, global->score, global->iterations);
  // ICP against the whole cropped scene, exactly as the ICP-only method would run.
  auto icp = RegisterPclIcp(model_base, scene_world, global->T_world_base, params.icp, false);
  if (!icp.ok()) return icp.status().WithContext("ICP refinement after " + std::string(name));
  out.step_ms.emplace_back("icp-refinement", laps.Lap());
  out.T_world_base = icp->T_world_base;
  out.iterations = icp->iterations;
  out.converged = icp->converged;
  out.score = global->score;
  out.hypotheses = global->iterations;
  out.stages.insert(out.stages.end(), icp->stages.begin(), icp->stages.end());
  return out;
}

}  // namespace arref
