// Which parts of a robot a joint motion moved. A map made while the robot worked holds its
// moving links smeared over the poses they passed through; a one-shot fit can rest on the links
// that stood still instead (the third class of Puljiz et al. 2019 asks that referencing not
// need the robot to stop).
#pragma once

#include <algorithm>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>

#include "arref/base/status.h"
#include "arref/robot/robot_model.h"

namespace arref {

// A joint that moved more than this while the map was made smeared the arm's mesh.
inline constexpr double kJointMotionWhileMappingRad = 0.02;
// ChooseMovingFit's rule (measured on the dev split: docs/robustness.md, "Joints moving while
// the map is made"): the unmoved links' least yaw leverage, in mesh voxels, and the least share
// of the model's surface that must have moved for leaving it out to pay (a moving wrist smears
// little, and the whole model fitted better there).
inline constexpr double kMovingFitMinLeverageVoxels = 2.0;
inline constexpr double kMovingFitMinMovedShare = 1.0 / 3.0;

// Per joint, the least and the most value seen over a time (rad or m).
using JointRanges = std::map<std::string, std::pair<double, double>>;

// Widens a joint's range to take in [lo, hi] (adds it when new).
inline void WidenRange(JointRanges& ranges, const std::string& joint, double lo, double hi) {
  auto [it, fresh] = ranges.try_emplace(joint, lo, hi);
  if (!fresh) it->second = {std::min(it->second.first, lo), std::max(it->second.second, hi)};
}

// The links with geometry whose pose in the base frame none of the joints in `ranges` moves:
// each joint whose range exceeds min_range is set to both ends of its range (the rest of the
// joints at `at`), and a link that moves either time moved. Found from the kinematics, so mimic
// joints and branched trees are handled. Names that are not actuated joints are an error.
Result<std::set<std::string>> UnmovedLinks(const RobotModel& robot, const JointValues& at, const JointRanges& ranges,
                                           double min_range);

// The links with geometry that no actuated joint moves, at any value within its limits: the
// base casting and what is bolted to it. Empty when every link with geometry moves.
Result<std::set<std::string>> FixedLinks(const RobotModel& robot);

// The height in the base frame of the surface the robot stands on. The base frame's origin sits
// on the mounting surface (the ROS-Industrial convention every vendor package here keeps); a
// fixed link reaching below it rests on its own lowest point instead. Only the fixed links
// count: an arm on a pedestal may reach below its mounting surface without lifting its base.
Result<double> RestingHeight(const RobotModel& robot);

// What a one-shot fit rests on when the joints moved by more than min_range while the map was
// made. The unmoved links, when the moving ones hold at least min_moved_share of the model's
// surface and the unmoved ones fix the heading on a mesh of this resolution: their yaw leverage
// (the root mean square moment arm of their surface about the base's vertical axis, what a
// point-to-plane fit's heading rests on once x, y and z are fitted) reaches min_leverage_voxels
// x mesh_voxel_m. Else every link: little moved, or too little of the robot stood still to fix
// its heading (the base of a Yaskawa MH5 is nearly a surface of revolution), so the smeared mesh
// is fitted whole and the result says so.
struct MovingFit {
  std::optional<std::set<std::string>> links;  // unset: every link
  std::set<std::string> unmoved;               // the links no moving joint carries
  double unmoved_area_share = 1.0;             // of the posed model's surface
  double yaw_leverage_m = 0.0;                 // of the unmoved links
  // The moving links hold at least min_moved_share of the surface: the map does not show the
  // robot as posed, whatever the fit rests on.
  bool much_moved = false;
};
Result<MovingFit> ChooseMovingFit(const RobotModel& robot, const JointValues& at, const JointRanges& ranges,
                                  double min_range, double mesh_voxel_m, double min_leverage_voxels,
                                  double min_moved_share);

}  // namespace arref
