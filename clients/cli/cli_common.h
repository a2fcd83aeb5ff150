// Pieces shared by the `arref` subcommands: exit codes, robot options, joint parsing.
#pragma once

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

#include "arref/base/frames.h"
#include "arref/base/geometry.h"
#include "arref/robot/robot_model.h"
#include "arref/base/status.h"
#include "client_io.h"  // poses, positions and joints as the subcommands read and write them

namespace arref::cli {

// Exit codes a script can rely on (also in README.md).
enum ExitCode : int {
  kExitOk = 0,
  kExitRegistrationFailed = 1,  // ran, but the result has status FAILED (no usable pose)
  kExitUsage = 2,               // bad command line
  kExitBadInput = 3,            // a named file or value is missing or malformed
  kExitCannotRun = 4,           // valid input that cannot be processed (e.g. nothing near the seed)
  kExitInternal = 5,
};
int ExitCodeFor(const Status& status);
// Logs the error and returns its exit code.
int Fail(const Status& status);

struct RobotArgs {
  std::string urdf;                      // empty: the built-in robot
  std::vector<std::string> package_path;
  std::string joints;                    // "name=rad,name=rad"
  bool collision = false;
};
void AddRobotOptions(CLI::App& app, RobotArgs& args);
Result<RobotModel> LoadRobot(const RobotArgs& args);
Result<JointValues> ParseJoints(const std::string& text);


// True when stderr is a terminal: progress lines are for people, not logs.
bool StderrIsTerminal();

}  // namespace arref::cli
