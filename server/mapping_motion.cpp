#include "mapping_motion.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace arref::server {

void MappingMotion::Add(const std::string& robot_id, const JointValues& joints) {
  JointRanges& ranges = ranges_[robot_id];
  for (const auto& [name, value] : joints) WidenRange(ranges, name, value, value);
}

JointRanges MappingMotion::For(const std::string& robot_id, const RobotModel& model) const {
  JointRanges merged;
  const std::vector<JointInfo> joints = model.ActuatedJoints();
  for (const std::string& id : {robot_id, std::string()}) {
    const auto it = ranges_.find(id);
    if (it == ranges_.end()) continue;
    for (const JointInfo& joint : joints)
      if (const auto range = it->second.find(joint.name); range != it->second.end())
        WidenRange(merged, joint.name, range->second.first, range->second.second);
    if (robot_id.empty()) break;
  }
  return merged;
}

double LargestRange(const JointRanges& ranges) {
  double most = 0.0;
  for (const auto& [name, range] : ranges) most = std::max(most, range.second - range.first);
  return most;
}

void AddMappingMotion(const JointRanges& ranges, const JobOutcome& outcome, wire::pb::Result* result) {
  const double motion = LargestRange(ranges);
  if (motion <= kJointMotionWhileMappingRad) return;
  result->set_joints_moved_while_mapping(true);
  result->set_joint_motion_rad(motion);
  std::string note = fmt::format(
      "the joints moved by up to {} rad while the map was made: the arm's mesh is smeared (TrackRequest with depth "
      "frames follows a moving robot)",
      std::round(motion * 100) / 100);  // {:.2f} would print every digit of 1e300
  if (!outcome.moving_fit_note.empty()) note += "; " + outcome.moving_fit_note;
  result->set_message(result->message() + (result->message().empty() ? "" : "; ") + note);
  for (const std::string& link : outcome.fitted_links) result->add_fitted_links(link);
}

}  // namespace arref::server
