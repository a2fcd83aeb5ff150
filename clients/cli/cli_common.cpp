#include "cli_common.h"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <sstream>

#include "arref/base/builtin.h"

namespace arref::cli {

int ExitCodeFor(const Status& status) {
  switch (status.code()) {
    case StatusCode::kOk: return kExitOk;
    case StatusCode::kInvalidArgument:
    case StatusCode::kNotFound:
    case StatusCode::kIoError: return kExitBadInput;
    case StatusCode::kFailedPrecondition:
    case StatusCode::kResourceExhausted:
    case StatusCode::kCancelled:
    case StatusCode::kUnavailable: return kExitCannotRun;
    case StatusCode::kInternal: return kExitInternal;
  }
  return kExitInternal;
}

int Fail(const Status& status) {
  spdlog::error("{}", status.ToString());
  return ExitCodeFor(status);
}

void AddRobotOptions(CLI::App& app, RobotArgs& args) {
  app.add_option("--robot", args.urdf, "Robot URDF (default: the built-in KR5-like robot)");
  app.add_option("--package-path", args.package_path,
                 "Folder holding ROS packages for package:// URIs (repeatable; ROS_PACKAGE_PATH is also used)");
  app.add_option("--joints", args.joints, "Joint values, name=rad,name=rad (unnamed joints: 0)");
  app.add_flag("--collision", args.collision, "Use collision geometry instead of visual");
}

Result<RobotModel> LoadRobot(const RobotArgs& args) {
  std::string urdf = args.urdf;
  if (urdf.empty()) {
    ARREF_ASSIGN_OR_RETURN(urdf, BuiltinRobotUrdf());
  }
  RobotLoadOptions options;
  options.package_path = args.package_path;
  options.geometry = args.collision ? GeometryKind::kCollision : GeometryKind::kVisual;
  return RobotModel::Load(urdf, options);
}


Result<JointValues> ParseJoints(const std::string& text) {
  JointValues joints;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');) {
    if (item.empty()) continue;
    const auto eq = item.find('=');
    if (eq == std::string::npos || eq == 0)
      return Status::InvalidArgument("--joints: '" + item + "' is not name=value");
    ARREF_ASSIGN_OR_RETURN(const std::vector<double> value,
                           ParseNumbers(item.substr(eq + 1), 1, "--joints " + item.substr(0, eq)));
    joints[item.substr(0, eq)] = value.front();
  }
  return joints;
}

bool StderrIsTerminal() { return isatty(STDERR_FILENO) != 0; }

}  // namespace arref::cli
