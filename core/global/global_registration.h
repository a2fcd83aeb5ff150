// Global registration methods (no reliance on the seed's pose beyond the crop and the
// segmentation): the paper's segmentation, Super4PCS, PCL's 4PCS / K-4PCS and FPFH + RANSAC,
// each followed by PCL ICP. Private to arref_baselines: RegisterGlobalThenIcp reaches them.
#pragma once

#include <functional>

#include "arref/baselines/baselines.h"

namespace arref {

// A global method's answer before ICP refinement.
struct GlobalAlignment {
  Iso3 T_world_base = Iso3::Identity();
  double score = 0.0;  // the method's own fitness (Super4PCS: LCP share of the scene sample)
  int iterations = 0;  // bases or RANSAC iterations tried
};

// The paper's segmentation (see SegmentationParams): scene points of the robot near the seed.
Result<PointCloud> SegmentNearSeed(const PointCloud& scene_world, const Iso3& T_world_seed,
                                   const PointCloud& model_base, const SegmentationParams& params);

Result<GlobalAlignment> AlignSuper4pcs(const PointCloud& model_base, const PointCloud& scene_world,
                                       const Super4pcsParams& params);
Result<GlobalAlignment> AlignPcl4pcs(const PointCloud& model_base, const PointCloud& scene_world,
                                     const Pcl4pcsParams& params, bool keypoint_variant);
Result<GlobalAlignment> AlignFpfhRansac(const PointCloud& model_base, const PointCloud& scene_world,
                                        const FpfhRansacParams& params);

}  // namespace arref
