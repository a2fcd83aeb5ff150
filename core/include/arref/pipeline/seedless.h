// Referencing with no seed: find the robot, and every other instance of it, in the whole spatial
// map (the paper's second class, automatic one-shot). The product's method (arref-auto) proposes
// candidate bases from the map's horizontal supports and the space the robot would fill above
// them, runs arref-icp from each as if the user had put a seed there, and keeps every distinct
// fit, ranked. Baselines (the paper's sliding box + SHOT, and any seeded method run on the whole
// map) give one candidate.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "arref/pipeline/pipeline.h"

namespace arref {

// Optional hints from the app to pick the primary instance among several: where the wearer
// looks (a gaze hit on the mesh) or where they stand, world frame.
struct InstanceHint {
  std::optional<Vec3> gaze_point_world;
  std::optional<Vec3> wearer_position_world;
};

// One instance found: a full registration report of it (pose, status, score, margin, timings of
// its own run) and the detection's score of the candidate it grew from.
struct FoundInstance {
  RegistrationReport report;
  double detection_score = 0.0;
  double explained = 0.0;      // share of the map samples round the fitted robot that lie on it
  double explained_bar = 0.0;  // the share a robot that is there reaches (below it: other surfaces)
};

struct WholeMapReport {
  ResultStatus status = ResultStatus::kFailed;  // the primary instance's; FAILED when none was found
  std::string status_reason;
  std::string method;
  std::vector<FoundInstance> instances;  // ranked by RanksBefore; never two within the robot's footprint
  int primary = -1;                      // index into instances, -1: none
  std::vector<std::string> stages_run;
  std::vector<StageTime> timings;        // the whole-map stages (each candidate's own are in its report)
  std::size_t scene_triangles = 0;
  int candidates = 0;                    // candidate bases the detection proposed
  double total_ms() const;
};

// The order of WholeMapReport::instances: OK fits, then fits placed but imprecise, then the rest
// (LOW_CONFIDENCE, then FAILED); within a tier by score, except that of two imprecise fits the one
// with the smaller expected error (FitPrecision::expected_error_m) comes first.
bool RanksBefore(const FoundInstance& a, const FoundInstance& b);

// Registers the robot against the whole map with options.method: arref-auto (the default here),
// sliding-box-shot, or any seeded method run from the map's centre over all of it.
Result<WholeMapReport> RegisterWholeMap(const RobotSide& robot, const TriangleMesh& scene_world,
                                        const RegistrationOptions& options, const InstanceHint& hint = {},
                                        const ProgressFn& progress = {}, const CancelToken* cancel = nullptr);

}  // namespace arref
