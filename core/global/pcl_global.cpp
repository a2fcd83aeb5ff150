// Global registration through PCL 1.13: 4PCS (Aiger et al. 2008), Keypoint-4PCS (Theiler et
// al. 2014) and FPFH (Rusu et al. 2009) + RANSAC with prerejection (Buch et al. 2013).
// Source = the model (base frame), target = the scene (world): PCL's answer is T_world_base.
#include <fmt/format.h>
#include <pcl/features/fpfh_omp.h>
#include <pcl/point_types.h>
#include <pcl/registration/ia_fpcs.h>
#include <pcl/registration/ia_kfpcs.h>
#include <pcl/registration/sample_consensus_prerejective.h>
#include <pcl/search/kdtree.h>

#include "global_registration.h"
#include "../baselines/pcl_cloud.h"
#include "arref/scene/sampling.h"

namespace arref {
namespace {

using PointN = pcl::PointNormal;
using CloudN = pcl::PointCloud<PointN>;


Iso3 ToIso(const Eigen::Matrix4f& M) {
  Iso3 T;
  T.matrix() = M.cast<double>();
  T.linear() = Quat(T.rotation()).normalized().toRotationMatrix();  // PCL works in float
  return T;
}

Status CheckSizes(const char* name, const CloudN& model, const CloudN& scene, std::size_t minimum) {
  if (model.size() >= minimum && scene.size() >= minimum) return Status::Ok();
  return Status::FailedPrecondition(fmt::format("{} needs at least {} model and scene points after downsampling (have {} and {})",
                                                name, minimum, model.size(), scene.size()));
}

// PCL keeps 4PCS's own fitness (1 - inlier share) protected; getFitnessScore() is an MSE.
template <typename Base>
class ScoredFpcs : public Base {
 public:
  float fitness() const { return this->fitness_score_; }
};

template <typename Aligner>
Result<GlobalAlignment> RunFpcs(Aligner& aligner, const CloudN::Ptr& model, const CloudN::Ptr& scene,
                                const Pcl4pcsParams& p) {
  aligner.setInputSource(model);
  aligner.setInputTarget(scene);
  aligner.setApproxOverlap(static_cast<float>(p.overlap));
  aligner.setDelta(static_cast<float>(p.delta_m), false);
  aligner.setNumberOfSamples(p.sample_count);
  aligner.setMaxComputationTime(p.max_time_s);
  aligner.setNumberOfThreads(1);
  CloudN aligned;
  aligner.align(aligned);
  if (!aligner.hasConverged())
    return Status::FailedPrecondition(fmt::format("no base match within {} s (delta {} m, overlap {})",
                                                  p.max_time_s, p.delta_m, p.overlap));
  GlobalAlignment out;
  out.T_world_base = ToIso(aligner.getFinalTransformation());
  out.score = 1.0 - aligner.fitness();
  return out;
}

pcl::PointCloud<pcl::FPFHSignature33>::Ptr Fpfh(const CloudN::Ptr& cloud, double radius) {
  pcl::FPFHEstimationOMP<PointN, PointN, pcl::FPFHSignature33> fpfh;
  fpfh.setNumberOfThreads(0);  // all cores
  fpfh.setInputCloud(cloud);
  fpfh.setInputNormals(cloud);
  fpfh.setSearchMethod(pcl::make_shared<pcl::search::KdTree<PointN>>());
  fpfh.setRadiusSearch(radius);
  auto features = pcl::make_shared<pcl::PointCloud<pcl::FPFHSignature33>>();
  fpfh.compute(*features);
  return features;
}

}  // namespace

Result<GlobalAlignment> AlignPcl4pcs(const PointCloud& model_base, const PointCloud& scene_world,
                                     const Pcl4pcsParams& p, bool keypoint_variant) {
  const char* name = keypoint_variant ? "pcl-k4pcs" : "pcl-4pcs";
  if (!(p.overlap > 0 && p.overlap <= 1) || !(p.delta_m > 0) || !(p.voxel_m > 0) || p.sample_count < 4 || p.max_time_s < 1)
    return Status::InvalidArgument(fmt::format(
        "{}: overlap must be in (0, 1], delta and voxel > 0 m, samples >= 4, max time >= 1 s", name));
  const auto model = ToPclUnitNormals(VoxelDownsample(model_base, p.voxel_m));
  const auto scene = ToPclUnitNormals(VoxelDownsample(scene_world, p.voxel_m));
  ARREF_RETURN_IF_ERROR(CheckSizes(name, *model, *scene, 4));
  if (keypoint_variant) {
    // K-4PCS proper runs on 3D keypoints; the voxel centroids stand in for them here.
    ScoredFpcs<pcl::registration::KFPCSInitialAlignment<PointN, PointN>> kfpcs;
    kfpcs.setScoreThreshold(0.001f);  // keep searching until the time budget: its default stops early
    return RunFpcs(kfpcs, model, scene, p);
  }
  ScoredFpcs<pcl::registration::FPCSInitialAlignment<PointN, PointN>> fpcs;
  return RunFpcs(fpcs, model, scene, p);
}

Result<GlobalAlignment> AlignFpfhRansac(const PointCloud& model_base, const PointCloud& scene_world,
                                        const FpfhRansacParams& p) {
  if (!(p.voxel_m > 0) || !(p.feature_radius_m > p.voxel_m) || !(p.max_correspondence_m > 0) || p.max_iterations <= 0 ||
      p.correspondence_randomness < 1 || !(p.similarity_threshold > 0 && p.similarity_threshold < 1) ||
      !(p.inlier_fraction > 0 && p.inlier_fraction <= 1))
    return Status::InvalidArgument(
        "fpfh-ransac: voxel > 0 m, feature radius > voxel, max correspondence > 0 m, iterations and randomness >= 1, "
        "similarity and inlier fraction in (0, 1) needed");
  if (!model_base.has_normals() || !scene_world.has_normals())
    return Status::FailedPrecondition("fpfh-ransac needs normals on the model and the scene");
  const auto model = ToPclUnitNormals(VoxelDownsample(model_base, p.voxel_m));
  const auto scene = ToPclUnitNormals(VoxelDownsample(scene_world, p.voxel_m));
  ARREF_RETURN_IF_ERROR(CheckSizes("fpfh-ransac", *model, *scene, 3));
  pcl::SampleConsensusPrerejective<PointN, PointN, pcl::FPFHSignature33> ransac;
  ransac.setInputSource(model);
  ransac.setSourceFeatures(Fpfh(model, p.feature_radius_m));
  ransac.setInputTarget(scene);
  ransac.setTargetFeatures(Fpfh(scene, p.feature_radius_m));
  ransac.setMaximumIterations(p.max_iterations);
  ransac.setNumberOfSamples(3);
  ransac.setCorrespondenceRandomness(p.correspondence_randomness);
  ransac.setSimilarityThreshold(static_cast<float>(p.similarity_threshold));
  ransac.setMaxCorrespondenceDistance(p.max_correspondence_m);
  ransac.setInlierFraction(static_cast<float>(p.inlier_fraction));
  CloudN aligned;
  ransac.align(aligned);
  if (!ransac.hasConverged())
    return Status::FailedPrecondition(fmt::format(
        "no pose with {:.0f} % of the model within {} m after {} iterations", p.inlier_fraction * 100,
        p.max_correspondence_m, p.max_iterations));
  GlobalAlignment out;
  out.T_world_base = ToIso(ransac.getFinalTransformation());
  out.score = static_cast<double>(ransac.getInliers().size()) / static_cast<double>(model->size());
  out.iterations = p.max_iterations;
  return out;
}

}  // namespace arref
