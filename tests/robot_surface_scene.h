// Clean data for the registration tests: two samplings of the built-in robot's own surface,
// one in the base frame, one placed in the world at a known pose.
#pragma once

#include "arref/pipeline/pipeline.h"
#include "test_support.h"

namespace arref::testing {

struct RobotSurfaceScene {
  PointCloud model_base;   // the robot's surface, base frame
  PointCloud scene_world;  // other samples of the same surface, placed at T_world_base
  Iso3 T_world_base;
};

// A Result, so that a robot that fails to load fails the test (ASSERT_OK_AND_ASSIGN) rather
// than being dereferenced.
inline Result<RobotSurfaceScene> MakeRobotSurfaceScene() {
  ARREF_ASSIGN_OR_RETURN(const RobotModel robot, RobotModel::Load(BuiltinRobotUrdf()));
  const JointValues joints = {{"joint_a2", -0.6}, {"joint_a3", 0.9}};
  RobotSurfaceScene c;
  ARREF_ASSIGN_OR_RETURN(c.model_base, SampleRobot(robot, joints, 6000, 1));
  ARREF_ASSIGN_OR_RETURN(c.scene_world, SampleRobot(robot, joints, 4000, 2));
  c.T_world_base = MakeYawPose(1.2, -0.7, 0.3, 2.0);
  c.scene_world.Transform(c.T_world_base);
  return c;
}

}  // namespace arref::testing
