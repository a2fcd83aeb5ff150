// Global method + ICP refinement: the paper's Super4PCS path (Puljiz et al. 2019, Sec. IV-B)
// generalised to any global aligner.
#include <spdlog/spdlog.h>

#include "global_registration.h"
#include "step_timer.h"

namespace arref {

Result<RegistrationOutput> RunGlobalThenIcp(const MethodInput& in, const char* name, const GlobalAlignFn& align) {
  RegistrationOutput out;
  StepTimer timer(&out);
  PointCloud segmented;
  const PointCloud* scene = &in.scene_world;
  if (in.options.segmentation.enabled) {
    auto seg = SegmentNearSeed(in.scene_world, in.T_world_seed, in.model_base, in.options.segmentation);
    if (!seg.ok()) return seg.status();
    segmented = std::move(*seg);
    scene = &segmented;
    out.stages.push_back("segment");
    timer.Step("segmentation");
  }
  auto global = align(in.model_base, *scene);
  if (!global.ok()) return global.status();  // the pipeline prefixes the method's name
  out.stages.push_back(name);
  timer.Step("global-alignment");
  spdlog::debug("{}: score {:.3f} after {} iterations", name, global->score, global->iterations);
  // ICP against the whole cropped scene, exactly as the ICP-only method would run.
  auto icp = RegisterPclIcp(in.model_base, in.scene_world, global->T_world_base, in.options.icp, false);
  if (!icp.ok()) return icp.status().WithContext("ICP refinement after " + std::string(name));
  timer.Step("icp-refinement");
  out.T_world_base = icp->T_world_base;
  out.iterations = icp->iterations;
  out.converged = icp->converged;
  out.score = global->score;
  out.hypotheses = global->iterations;
  out.stages.insert(out.stages.end(), icp->stages.begin(), icp->stages.end());
  return out;
}

}  // namespace arref
