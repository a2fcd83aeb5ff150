// How the clients read and write poses, positions, matrices and joint states: as JSON (the cell
// files `arref simulate` writes, which the `arref` command line and the mock headset both read, so
// one reader checks them) and as the comma-separated numbers a user types for a pose; and the
// line both print a result's expected error as.
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <string>
#include <vector>

#include "arref/base/frames.h"
#include "arref/base/geometry.h"
#include "arref/robot/robot_model.h"
#include "arref/base/status.h"

namespace arref {

// x, y, z, qx, qy, qz, qw in the given convention, to an internal pose; the quaternion must be
// unit length (to 1e-3), so a typo is an error rather than a silently normalised rotation.
Result<Iso3> PoseFromNumbers(const std::vector<double>& numbers, FrameConvention frame);
// Exactly `count` finite comma-separated numbers; `what` names them in the error.
Result<std::vector<double>> ParseNumbers(const std::string& text, std::size_t count, const std::string& what);
// "x,y,z,qx,qy,qz,qw" in the given convention, to an internal pose.
Result<Iso3> ParsePose(const std::string& text, FrameConvention frame);

// Row-major 4x4 as 16 numbers, and back.
nlohmann::json MatrixToJson(const Iso3& T);
Result<Iso3> MatrixFromJson(const nlohmann::json& j);
// [x,y,z,qx,qy,qz,qw] of an internal pose, in the given convention, and back.
nlohmann::json PoseToJson(const Iso3& T, FrameConvention frame);
Result<Iso3> PoseFromJson(const nlohmann::json& j, FrameConvention frame);
// [[x,y,z], ...] of internal positions (a head path), in the given convention, and back.
nlohmann::json PositionsToJson(const std::vector<Vec3>& positions, FrameConvention frame);
Result<std::vector<Vec3>> PositionsFromJson(const nlohmann::json& j, FrameConvention frame);
// {"joint": value, ...}, rad or m.
Result<JointValues> JointsFromJson(const nlohmann::json& j);

// The frame convention a cell file's numbers are in: its "frame", "ros" when it has none.
Result<FrameConvention> FrameOfFile(const nlohmann::json& file);

// A JSON file whose top level is an object (every file arref reads is one).
Result<nlohmann::json> ReadJsonFile(const std::string& path);
Status WriteJsonFile(const nlohmann::json& j, const std::string& path);

// "expected error 4.4 mm (the fit 0.9 mm, the map 3.7 mm, the surface model 2.3 mm)", from
// Result.expected_error_m and its parts (metres).
std::string ExpectedErrorLine(double total_m, double fit_m, double map_m, double surface_m);

}  // namespace arref
