// Parameters of the comparison methods (the paper's ICP, global methods, MLS). Plain structs
// with no PCL in sight: the options of a request name them whether or not arref was built
// with the baselines (ARREF_WITH_PCL).
#pragma once

#include <cstdint>
#include <string>

#include "arref/base/status.h"

namespace arref {

// The paper's ICP knobs (PCL IterativeClosestPoint). Defaults: its best "small" setting.
struct IcpParams {
  double max_correspondence_m = 0.1;
  int max_iterations = 500;
  double transformation_epsilon = 1e-8;  // PCL: squared change of the transform between iterations
  double euclidean_fitness_epsilon = 1e-8;
};

// The paper's segmentation before a global method (Puljiz et al. 2019, Sec. IV-B): remove
// large planes (floor, walls, table top) with RANSAC, cluster the rest (Euclidean), keep the
// cluster nearest the seed. A kept part much wider than the robot means the robot touches
// other objects (e.g. a table): reported as an error, not registered.
struct SegmentationParams {
  bool enabled = true;
  double plane_distance_m = 0.02;     // RANSAC plane inlier band
  double min_plane_fraction = 0.08;   // a plane is "large" with at least this share of the points
  int max_planes = 4;
  double cluster_tolerance_m = 0.05;  // Euclidean clustering: neighbour distance
  std::size_t min_cluster_points = 20;
  double seed_radius_m = 0.35;        // keep the cluster nearest the seed's vertical axis, if this close
  double max_extent_ratio = 1.5;      // kept width > ratio x robot width: robot touches something
};

// Super4PCS (Mellado, Aiger, Mitra, SGP 2014). Lengths in metres; 0 means derive from the
// model's size (users mostly fail on these scales).
struct Super4pcsParams {
  double overlap = 0.6;            // expected share of the (segmented) scene that is robot
  double delta_m = 0.0;            // accuracy; 0: 1.5 % of the model diagonal, clamped to [1, 3] cm
  std::size_t sample_count = 500;  // points drawn from each cloud for the search
  int max_bases = 300;             // iterations (bases tried)
  double max_time_s = 5.0;
  double max_tilt_deg = 15.0;      // the headset knows gravity: reject tilted candidates (180: off)
  double terminate_lcp = 0.85;     // stop when this share of the scene sample is matched
  std::uint64_t rng_seed = 1;
};

// PCL's 4PCS (FPCSInitialAlignment) and Keypoint-4PCS (KFPCSInitialAlignment).
struct Pcl4pcsParams {
  double overlap = 0.6;
  double delta_m = 0.02;
  int sample_count = 500;
  double voxel_m = 0.03;  // both clouds are voxel-downsampled first (K-4PCS: these are its keypoints)
  int max_time_s = 5;
};

// FPFH features (Rusu et al. 2009) + RANSAC with prerejection (Buch et al. 2013), through PCL.
struct FpfhRansacParams {
  double voxel_m = 0.025;
  double normal_radius_m = 0.06;
  double feature_radius_m = 0.12;
  int max_iterations = 20000;
  int correspondence_randomness = 5;
  double similarity_threshold = 0.85;  // edge-length ratio of the prerejection
  double max_correspondence_m = 0.04;
  double inlier_fraction = 0.2;
};

// Moving Least Squares (PCL MovingLeastSquares), the paper's optional resampling step.
struct MlsOptions {
  double search_radius_m = 0.05;
  int polynomial_order = 2;
  enum class Upsampling { kNone, kSampleLocalPlane, kRandomUniformDensity, kVoxelGridDilation };
  Upsampling upsampling = Upsampling::kNone;
  double upsampling_radius_m = 0.01;  // kSampleLocalPlane
  double upsampling_step_m = 0.005;   // kSampleLocalPlane
  int point_density = 20;             // kRandomUniformDensity
  double dilation_voxel_m = 0.01;     // kVoxelGridDilation
};

inline Result<MlsOptions::Upsampling> ParseMlsUpsampling(const std::string& name) {
  using U = MlsOptions::Upsampling;
  if (name == "none") return U::kNone;
  if (name == "sample-local-plane") return U::kSampleLocalPlane;
  if (name == "random-uniform-density") return U::kRandomUniformDensity;
  if (name == "voxel-grid-dilation") return U::kVoxelGridDilation;
  return Status::InvalidArgument("unknown MLS upsampling '" + name +
                                 "' (expected none, sample-local-plane, random-uniform-density, voxel-grid-dilation)");
}

// The paper's proposal for automatic referencing (Puljiz et al. 2019, Sec. VI): a box of the
// robot's bounding-box size slid over the scene, SHOT descriptors of the boxes matched against
// the model's, ICP from the best box at four yaws.
struct SlidingBoxParams {
  double step_fraction = 0.2;       // slide step, as a fraction of the box side (the paper's 0.2)
  double min_points_fraction = 0.3; // boxes with fewer points than this share of the model's are dropped
  double leaf_m = 0.03;             // both clouds voxel-downsampled first
  int icp_yaws = 4;                 // ICP from the best box's centre, 360 / icp_yaws degrees apart
};

}  // namespace arref
