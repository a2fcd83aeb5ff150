// Joint motion while the map was made: a session's (and a replay's) record of each joint's range
// over the joint states sent since its first surface, and what the Result says about it.
#pragma once

#include <map>
#include <string>

#include "arref/robot/joint_motion.h"
#include "arref/robot/robot_model.h"
#include "job_scheduler.h"
#include "wire.h"

namespace arref::server {

class MappingMotion {
 public:
  // A joint state accepted while the session held surfaces.
  void Add(const std::string& robot_id, const JointValues& joints);
  // The range of each of the robot's actuated joints, over the states sent for this robot id and
  // those that named no robot ("", which RequestJoints applies to every robot). Joints the robot
  // does not have are left out, so the Result's flag and the fit (MovingFitLinks) see one motion.
  JointRanges For(const std::string& robot_id, const RobotModel& model) const;

 private:
  std::map<std::string, JointRanges> ranges_;  // by robot id
};

// The largest range of one joint.
double LargestRange(const JointRanges& ranges);

// Marks a Result whose map was made while a joint moved more than kJointMotionWhileMappingRad:
// joints_moved_while_mapping, joint_motion_rad, fitted_links and the message (the outcome's
// note on what the fit rested on). Nothing when no joint moved.
void AddMappingMotion(const JointRanges& ranges, const JobOutcome& outcome, wire::pb::Result* result);

}  // namespace arref::server
