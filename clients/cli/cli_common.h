// Pieces shared by the `arref` subcommands: exit codes, robot options, pose and JSON helpers.
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json_fwd.hpp>

#include <string>
#include <vector>

#include "arref/frames.h"
#include "arref/geometry.h"
#include "arref/robot_model.h"
#include "arref/status.h"

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

// "x,y,z,qx,qy,qz,qw" in the given convention, to an internal pose.
Result<Iso3> ParsePose(const std::string& text, FrameConvention frame);

// Row-major 4x4 as 16 numbers, and back.
nlohmann::json MatrixToJson(const Iso3& T);
Result<Iso3> MatrixFromJson(const nlohmann::json& j);
// [x,y,z,qx,qy,qz,qw] of an internal pose, in the given convention.
nlohmann::json PoseToJson(const Iso3& T, FrameConvention frame);
Result<Iso3> PoseFromJson(const nlohmann::json& j, FrameConvention frame);

// [[x,y,z], ...] of internal positions (a head path), in the given convention, and back.
nlohmann::json PositionsToJson(const std::vector<Vec3>& positions, FrameConvention frame);
Result<std::vector<Vec3>> PositionsFromJson(const nlohmann::json& j, FrameConvention frame);

Result<nlohmann::json> ReadJsonFile(const std::string& path);
Status WriteJsonFile(const nlohmann::json& j, const std::string& path);

// True when stderr is a terminal: progress lines are for people, not logs.
bool StderrIsTerminal();

}  // namespace arref::cli
