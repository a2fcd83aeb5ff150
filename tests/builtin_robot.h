// The built-in robot (config/robots/kr5_primitive.urdf), loaded once per test process for the
// tests that pose it many times.
#pragma once

#include <stdexcept>

#include "arref/robot/robot_model.h"
#include "test_support.h"

namespace arref::testing {

inline const RobotModel& BuiltinRobot() {
  static const RobotModel robot = [] {
    auto r = RobotModel::Load(BuiltinRobotUrdf());
    if (!r.ok()) throw std::runtime_error(r.status().ToString());
    return std::move(r).value();
  }();
  return robot;
}

}  // namespace arref::testing
