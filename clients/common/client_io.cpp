#include "client_io.h"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

namespace arref {

Result<Iso3> PoseFromNumbers(const std::vector<double>& n, FrameConvention frame) {
  if (n.size() != 7) return Status::InvalidArgument("a pose is 7 numbers x,y,z,qx,qy,qz,qw");
  const Quat q(n[6], n[3], n[4], n[5]);
  if (std::abs(q.norm() - 1.0) > 1e-3)
    return Status::InvalidArgument("pose quaternion is not unit length (norm " + std::to_string(q.norm()) + ")");
  return PoseToRos(Vec3(n[0], n[1], n[2]), q, frame);
}

Result<std::vector<double>> ParseNumbers(const std::string& text, std::size_t count, const std::string& what) {
  std::vector<double> values;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');) {
    try {
      std::size_t used = 0;
      values.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      return Status::InvalidArgument(what + ": '" + item + "' is not a number");
    }
    if (!std::isfinite(values.back())) return Status::InvalidArgument(what + ": '" + item + "' is not finite");
  }
  if (values.size() != count)
    return Status::InvalidArgument(what + ": expected " + std::to_string(count) + " comma-separated numbers, got " +
                                   std::to_string(values.size()));
  return values;
}

Result<Iso3> ParsePose(const std::string& text, FrameConvention frame) {
  ARREF_ASSIGN_OR_RETURN(const std::vector<double> v, ParseNumbers(text, 7, "pose x,y,z,qx,qy,qz,qw"));
  return PoseFromNumbers(v, frame);
}

nlohmann::json MatrixToJson(const Iso3& T) {
  nlohmann::json j = nlohmann::json::array();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) j.push_back(T.matrix()(r, c));
  return j;
}

Result<Iso3> MatrixFromJson(const nlohmann::json& j) {
  if (!j.is_array() || j.size() != 16) return Status::InvalidArgument("a 4x4 matrix must be 16 numbers, row-major");
  Iso3 T;
  for (int i = 0; i < 16; ++i) {
    if (!j[i].is_number()) return Status::InvalidArgument("matrix element " + std::to_string(i) + " is not a number");
    T.matrix()(i / 4, i % 4) = j[i].get<double>();
  }
  return T;
}

nlohmann::json PoseToJson(const Iso3& T, FrameConvention frame) {
  Vec3 p;
  Quat q;
  PoseFromRos(T, frame, &p, &q);
  return {p.x(), p.y(), p.z(), q.x(), q.y(), q.z(), q.w()};
}

Result<Iso3> PoseFromJson(const nlohmann::json& j, FrameConvention frame) {
  if (!j.is_array() || j.size() != 7) return Status::InvalidArgument("a pose must be [x,y,z,qx,qy,qz,qw]");
  std::vector<double> n;
  for (const auto& v : j) {
    if (!v.is_number()) return Status::InvalidArgument("a pose element is not a number");
    n.push_back(v.get<double>());
  }
  return PoseFromNumbers(n, frame);
}

nlohmann::json PositionsToJson(const std::vector<Vec3>& positions, FrameConvention frame) {
  nlohmann::json out = nlohmann::json::array();
  for (const Vec3& p : positions) {
    const Vec3 q = PositionFromRos(p, frame);
    out.push_back({q.x(), q.y(), q.z()});
  }
  return out;
}

Result<std::vector<Vec3>> PositionsFromJson(const nlohmann::json& j, FrameConvention frame) {
  if (!j.is_array()) return Status::InvalidArgument("positions must be an array of [x,y,z]");
  std::vector<Vec3> out;
  for (const auto& p : j) {
    const std::string where = "position " + std::to_string(out.size());
    if (!p.is_array() || p.size() != 3 || !p[0].is_number() || !p[1].is_number() || !p[2].is_number())
      return Status::InvalidArgument(where + " is not [x,y,z]");
    const Vec3 v(p[0].get<double>(), p[1].get<double>(), p[2].get<double>());
    if (!v.allFinite()) return Status::InvalidArgument(where + " is not finite");
    out.push_back(PositionToRos(v, frame));
  }
  return out;
}

Result<JointValues> JointsFromJson(const nlohmann::json& j) {
  if (!j.is_object()) return Status::InvalidArgument("joints must be an object of name: value");
  JointValues joints;
  for (const auto& [name, value] : j.items()) {
    if (!value.is_number() || !std::isfinite(value.get<double>()))
      return Status::InvalidArgument("joint '" + name + "' is not a finite number");
    joints[name] = value.get<double>();
  }
  return joints;
}

Result<FrameConvention> FrameOfFile(const nlohmann::json& file) {
  if (!file.contains("frame")) return FrameConvention::kRos;
  if (!file["frame"].is_string()) return Status::InvalidArgument("frame must be a string such as \"ros\" or \"unity\"");
  return ParseFrameConvention(file["frame"].get<std::string>());
}

Result<nlohmann::json> ReadJsonFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound("cannot open " + path);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    return Status::IoError(path + " is not valid JSON: " + e.what());
  }
  if (!j.is_object()) return Status::InvalidArgument(path + " is not a JSON object");
  return j;
}

Status WriteJsonFile(const nlohmann::json& j, const std::string& path) {
  std::ofstream out(path);
  if (!out) return Status::IoError("cannot write " + path);
  out << j.dump(2) << "\n";
  return out ? Status::Ok() : Status::IoError("error writing " + path);
}

std::string ExpectedErrorLine(double total_m, double fit_m, double map_m, double surface_m) {
  return fmt::format("expected error {:.1f} mm (the fit {:.1f} mm, the map {:.1f} mm, the surface model {:.1f} mm)",
                     total_m * 1e3, fit_m * 1e3, map_m * 1e3, surface_m * 1e3);
}

}  // namespace arref
