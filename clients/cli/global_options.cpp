#include "global_options.h"

namespace arref::cli {

void AddGlobalMethodOptions(CLI::App& cmd, RegistrationOptions& o) {
  const char* g = "Global methods (super4pcs, pcl-4pcs, pcl-k4pcs, fpfh-ransac)";
  SegmentationParams& seg = o.segmentation;
  cmd.add_flag("--no-segmentation{false}", seg.enabled, "Skip the plane removal + clustering before a global method")
      ->group(g);
  cmd.add_option("--seg-plane-distance", seg.plane_distance_m, "Segmentation: RANSAC plane band, m")->group(g)->capture_default_str();
  cmd.add_option("--seg-cluster-tolerance", seg.cluster_tolerance_m, "Segmentation: Euclidean cluster tolerance, m")
      ->group(g)->capture_default_str();
  cmd.add_option("--seg-seed-radius", seg.seed_radius_m, "Segmentation: keep clusters this close to the seed axis, m")
      ->group(g)->capture_default_str();
  cmd.add_option("--seg-max-extent-ratio", seg.max_extent_ratio,
                 "Segmentation: fail when the kept part is this many times wider than the robot")->group(g)->capture_default_str();
  Super4pcsParams& s = o.super4pcs;
  cmd.add_option("--s4pcs-overlap", s.overlap, "Super4PCS: expected overlap in (0, 1]")->group(g)->capture_default_str();
  cmd.add_option("--s4pcs-delta", s.delta_m, "Super4PCS: accuracy delta, m (0: 1.5 % of the model diagonal, 1-3 cm)")
      ->group(g)->capture_default_str();
  cmd.add_option("--s4pcs-samples", s.sample_count, "Super4PCS: points drawn from each cloud")->group(g)->capture_default_str();
  cmd.add_option("--s4pcs-max-bases", s.max_bases, "Super4PCS: bases to try")->group(g)->capture_default_str();
  cmd.add_option("--s4pcs-max-time", s.max_time_s, "Super4PCS: time budget, s")->group(g)->capture_default_str();
  cmd.add_option("--s4pcs-max-tilt", s.max_tilt_deg, "Super4PCS: reject candidates tilted more than this from upright, deg (180: off)")
      ->group(g)->capture_default_str();
  Pcl4pcsParams& f = o.pcl_4pcs;
  cmd.add_option("--pcl4pcs-overlap", f.overlap, "PCL 4PCS / K-4PCS: approximate overlap")->group(g)->capture_default_str();
  cmd.add_option("--pcl4pcs-delta", f.delta_m, "PCL 4PCS / K-4PCS: delta, m")->group(g)->capture_default_str();
  cmd.add_option("--pcl4pcs-samples", f.sample_count, "PCL 4PCS / K-4PCS: samples")->group(g)->capture_default_str();
  cmd.add_option("--pcl4pcs-voxel", f.voxel_m, "PCL 4PCS / K-4PCS: voxel leaf before the search, m")->group(g)->capture_default_str();
  cmd.add_option("--pcl4pcs-max-time", f.max_time_s, "PCL 4PCS / K-4PCS: time budget, s")->group(g)->capture_default_str();
  FpfhRansacParams& r = o.fpfh_ransac;
  cmd.add_option("--fpfh-voxel", r.voxel_m, "FPFH + RANSAC: voxel leaf, m")->group(g)->capture_default_str();
  cmd.add_option("--fpfh-radius", r.feature_radius_m, "FPFH + RANSAC: feature radius, m")->group(g)->capture_default_str();
  cmd.add_option("--fpfh-iterations", r.max_iterations, "FPFH + RANSAC: RANSAC iterations")->group(g)->capture_default_str();
  cmd.add_option("--fpfh-max-correspondence", r.max_correspondence_m, "FPFH + RANSAC: inlier distance, m")
      ->group(g)->capture_default_str();
}

}  // namespace arref::cli
