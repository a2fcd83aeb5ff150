#include "server_config.h"

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <boost/asio/ip/address.hpp>

#include <filesystem>
#include <limits>
#include <set>
#include <type_traits>

#include "arref/base/builtin.h"
#include "arref/base/files.h"

namespace arref::server {
namespace {

namespace fs = std::filesystem;

Status CheckKeys(const YAML::Node& node, const std::string& where, const std::set<std::string>& known) {
  if (!node.IsMap()) return Status::InvalidArgument(where + ": expected a mapping");
  for (const auto& kv : node) {
    const std::string key = kv.first.as<std::string>();
    if (!known.count(key)) {
      std::string list;
      for (const auto& k : known) list += (list.empty() ? "" : ", ") + k;
      return Status::InvalidArgument(where + ": unknown key '" + key + "' (known: " + list + ")");
    }
  }
  return Status::Ok();
}

// What a value of type T must be, for the error that says it is not.
template <typename T>
std::string Expected() {
  if constexpr (std::is_same_v<T, bool>) return "true or false";
  else if constexpr (std::is_unsigned_v<T> && sizeof(T) < sizeof(int))
    return "a whole number in 0.." + std::to_string(std::numeric_limits<T>::max());
  else if constexpr (std::is_unsigned_v<T>) return "a whole number >= 0";
  else if constexpr (std::is_integral_v<T>) return "a whole number";
  else if constexpr (std::is_floating_point_v<T>) return "a number";
  else return "a string";
}

// yaml-cpp's own conversion error names neither the key nor the value ("bad conversion").
template <typename T>
T As(const YAML::Node& value, const std::string& name) {
  try {
    return value.as<T>();
  } catch (const YAML::BadConversion& e) {
    const std::string shown = value.IsScalar() ? "'" + value.Scalar() + "'" : "a list or mapping";
    throw YAML::Exception(e.mark, name + ": " + shown + " is not " + Expected<T>());
  }
}

template <typename T>
void Read(const YAML::Node& node, const char* key, T& out) {
  if (const YAML::Node value = node[key]) out = As<T>(value, key);
}

std::string Resolve(const std::string& path, const std::string& base_dir) {
  const fs::path p(path);
  return p.is_absolute() ? p.string() : (fs::path(base_dir) / p).lexically_normal().string();
}

Status ReadServer(const YAML::Node& n, ServerConfig& c) {
  ARREF_RETURN_IF_ERROR(CheckKeys(n, "server", {"address", "port", "io_threads", "workers", "queue_size",
                                                "idle_timeout_s", "hello_timeout_s", "frame_timeout_s", "send_timeout_s", "shutdown_grace_s",
                                                "auth_token", "allow_plaintext_token", "log_level", "record_dir"}));
  Read(n, "address", c.address);
  Read(n, "port", c.port);
  Read(n, "io_threads", c.io_threads);
  Read(n, "workers", c.workers);
  Read(n, "queue_size", c.queue_size);
  Read(n, "idle_timeout_s", c.idle_timeout_s);
  Read(n, "hello_timeout_s", c.hello_timeout_s);
  Read(n, "frame_timeout_s", c.frame_timeout_s);
  Read(n, "send_timeout_s", c.send_timeout_s);
  Read(n, "shutdown_grace_s", c.shutdown_grace_s);
  Read(n, "auth_token", c.auth_token);
  Read(n, "allow_plaintext_token", c.allow_plaintext_token);
  Read(n, "log_level", c.log_level);
  Read(n, "record_dir", c.record_dir);
  return Status::Ok();
}

Status ReadTls(const YAML::Node& n, const std::string& base_dir, TlsConfig& t) {
  ARREF_RETURN_IF_ERROR(CheckKeys(n, "tls", {"certificate_chain", "private_key", "client_ca"}));
  Read(n, "certificate_chain", t.certificate_chain);
  Read(n, "private_key", t.private_key);
  Read(n, "client_ca", t.client_ca);
  for (std::string* path : {&t.certificate_chain, &t.private_key, &t.client_ca})
    if (!path->empty()) *path = Resolve(*path, base_dir);
  return Status::Ok();
}

Status ReadLimits(const YAML::Node& n, ServerLimits& l) {
  ARREF_RETURN_IF_ERROR(CheckKeys(
      n, "limits", {"max_message_bytes", "max_sessions", "max_pending_connections", "max_connections_per_peer",
                    "max_surfaces_per_session", "max_vertices_per_session", "max_triangles_per_session",
                    "max_mesh_bytes_per_session", "memory_budget_bytes", "max_requests_per_session",
                    "max_send_queue_bytes", "max_send_queue_messages", "max_map_triangles"}));
  Read(n, "max_message_bytes", l.max_message_bytes);
  Read(n, "max_sessions", l.max_sessions);
  Read(n, "max_pending_connections", l.max_pending_connections);
  Read(n, "max_connections_per_peer", l.max_connections_per_peer);
  Read(n, "max_surfaces_per_session", l.max_surfaces_per_session);
  Read(n, "max_vertices_per_session", l.max_vertices_per_session);
  Read(n, "max_triangles_per_session", l.max_triangles_per_session);
  Read(n, "max_mesh_bytes_per_session", l.max_mesh_bytes_per_session);
  Read(n, "memory_budget_bytes", l.memory_budget_bytes);
  Read(n, "max_requests_per_session", l.max_requests_per_session);
  Read(n, "max_send_queue_bytes", l.max_send_queue_bytes);
  Read(n, "max_send_queue_messages", l.max_send_queue_messages);
  Read(n, "max_map_triangles", l.max_map_triangles);
  return Status::Ok();
}

Status ReadRegistration(const YAML::Node& n, ServerConfig& c) {
  ARREF_RETURN_IF_ERROR(CheckKeys(n, "registration", {"method", "crop_radius_m", "scene_samples", "model_samples",
                                                      "icp_max_correspondence_m", "icp_max_iterations",
                                                      "inlier_threshold_m", "sample_seed", "model_cache_entries",
                                                      "tracking_error_m", "tracking_error_deg"}));
  RegistrationOptions& o = c.registration;
  if (n["method"]) {
    auto method = ParseMethod(As<std::string>(n["method"], "method"));
    if (!method.ok()) return method.status().WithContext("registration.method");
    o.method = *method;
  }
  Read(n, "crop_radius_m", o.crop_radius_m);
  Read(n, "scene_samples", o.scene_samples);
  Read(n, "model_samples", o.model_samples);
  Read(n, "icp_max_correspondence_m", o.icp.max_correspondence_m);
  Read(n, "icp_max_iterations", o.icp.max_iterations);
  Read(n, "inlier_threshold_m", o.inlier_threshold_m);
  Read(n, "sample_seed", o.sample_seed);
  Read(n, "model_cache_entries", c.model_cache_entries);
  Read(n, "tracking_error_m", o.arref_icp.tracking_error.position_m);
  Read(n, "tracking_error_deg", o.arref_icp.tracking_error.orientation_deg);
  return Status::Ok();
}

Result<RobotConfig> ReadRobot(const YAML::Node& n, std::size_t index, const std::string& base_dir) {
  const std::string where = "robots[" + std::to_string(index) + "]";
  ARREF_RETURN_IF_ERROR(CheckKeys(n, where, {"id", "urdf", "package_path", "default_joints"}));
  RobotConfig r;
  Read(n, "id", r.id);
  Read(n, "urdf", r.urdf);
  if (r.id.empty()) return Status::InvalidArgument(where + ": 'id' is required");
  if (r.urdf.empty()) return Status::InvalidArgument(where + " (" + r.id + "): 'urdf' is required (a path or 'builtin')");
  if (r.urdf == "builtin") {
    auto urdf = BuiltinRobotUrdf();
    if (!urdf.ok()) return urdf.status().WithContext(where + " urdf: builtin");
    r.urdf = *urdf;
  } else {
    r.urdf = Resolve(r.urdf, base_dir);
  }
  if (n["package_path"]) {
    const YAML::Node pp = n["package_path"];
    if (pp.IsScalar()) r.package_path.push_back(Resolve(As<std::string>(pp, "package_path"), base_dir));
    else
      for (const auto& p : pp) r.package_path.push_back(Resolve(As<std::string>(p, "package_path"), base_dir));
  }
  if (n["default_joints"]) {
    if (!n["default_joints"].IsMap()) return Status::InvalidArgument(where + ".default_joints: expected name: value");
    for (const auto& kv : n["default_joints"]) {
      const auto name = kv.first.as<std::string>();
      r.default_joints[name] = As<double>(kv.second, "default_joints." + name);
    }
  }
  return r;
}

Status ReadRobots(const YAML::Node& n, const std::string& base_dir, ServerConfig& c) {
  if (!n.IsSequence()) return Status::InvalidArgument("robots: expected a list");
  std::set<std::string> ids;
  for (std::size_t i = 0; i < n.size(); ++i) {
    ARREF_ASSIGN_OR_RETURN(RobotConfig robot, ReadRobot(n[i], i, base_dir));
    if (!ids.insert(robot.id).second) return Status::InvalidArgument("robots: duplicate id '" + robot.id + "'");
    c.robots.push_back(std::move(robot));
  }
  return Status::Ok();
}

Status ReadAll(const YAML::Node& root, const std::string& base_dir, ServerConfig& c) {
  ARREF_RETURN_IF_ERROR(CheckKeys(root, "config", {"server", "tls", "limits", "registration", "robots"}));
  if (root["server"]) ARREF_RETURN_IF_ERROR(ReadServer(root["server"], c));
  if (root["tls"]) ARREF_RETURN_IF_ERROR(ReadTls(root["tls"], base_dir, c.tls));
  if (root["limits"]) ARREF_RETURN_IF_ERROR(ReadLimits(root["limits"], c.limits));
  if (root["registration"]) ARREF_RETURN_IF_ERROR(ReadRegistration(root["registration"], c));
  if (root["robots"]) ARREF_RETURN_IF_ERROR(ReadRobots(root["robots"], base_dir, c));
  return Status::Ok();
}

bool IsLoopback(const std::string& address) {
  boost::system::error_code ec;
  const auto parsed = boost::asio::ip::make_address(address, ec);
  return !ec && parsed.is_loopback();
}

Status ValidateTls(const TlsConfig& t) {
  if (t.certificate_chain.empty() != t.private_key.empty())
    return Status::InvalidArgument("tls: certificate_chain and private_key go together (one is set, the other empty)");
  if (!t.client_ca.empty() && !t.enabled())
    return Status::InvalidArgument("tls.client_ca is set but TLS is off: set tls.certificate_chain and tls.private_key");
  return Status::Ok();
}

}  // namespace

std::string ClearTextTokenRisk(const ServerConfig& c) {
  if (c.auth_token.empty() || c.tls.enabled() || IsLoopback(c.address)) return "";
  return fmt::format("server.auth_token is set, TLS is off and the server listens on {}, which is not loopback: "
                     "every headset's token would cross the network in clear text", c.address);
}

Status ValidateServerConfig(const ServerConfig& c) {
  if (c.robots.empty()) return Status::InvalidArgument("no robots configured (robots: [...])");
  if (c.workers < 1 || c.workers > 256) return Status::InvalidArgument("server.workers must be 1..256");
  if (c.io_threads < 1 || c.io_threads > 64) return Status::InvalidArgument("server.io_threads must be 1..64");
  if (c.queue_size < 1) return Status::InvalidArgument("server.queue_size must be >= 1");
  if (!(c.idle_timeout_s > 0) || !(c.send_timeout_s > 0) || !(c.shutdown_grace_s >= 0) || !(c.hello_timeout_s > 0) ||
      !(c.frame_timeout_s > 0))
    return Status::InvalidArgument("server timeouts must be > 0 s");
  if (c.limits.max_message_bytes < 64) return Status::InvalidArgument("limits.max_message_bytes must be >= 64");
  if (c.limits.max_sessions < 1) return Status::InvalidArgument("limits.max_sessions must be >= 1");
  if (c.limits.max_pending_connections < 1 || c.limits.max_connections_per_peer < 1)
    return Status::InvalidArgument("limits.max_pending_connections and max_connections_per_peer must be >= 1");
  if (c.limits.memory_budget_bytes < (64u << 20))
    return Status::InvalidArgument(fmt::format("limits.memory_budget_bytes ({}) must be >= 64 MiB (67108864)",
                                               c.limits.memory_budget_bytes));
  if (c.registration.model_samples < 3) return Status::InvalidArgument("registration.model_samples must be >= 3");
  const TrackingError& e = c.registration.arref_icp.tracking_error;
  if (!(e.position_m >= 0 && e.position_m <= 1) || !(e.orientation_deg >= 0 && e.orientation_deg <= 30))
    return Status::InvalidArgument(fmt::format(
        "registration.tracking_error_m ({}) must be in [0, 1] and tracking_error_deg ({}) in [0, 30]", e.position_m,
        e.orientation_deg));
  ARREF_RETURN_IF_ERROR(ValidateTls(c.tls));
  if (const std::string risk = ClearTextTokenRisk(c); !risk.empty() && !c.allow_plaintext_token)
    return Status::InvalidArgument(risk + ". Configure tls (certificate_chain, private_key), listen on 127.0.0.1, or set "
                                   "server.allow_plaintext_token: true if the network is trusted");
  return Status::Ok();
}

std::string RegistrationYaml(const ServerConfig& c) {
  const RegistrationOptions& o = c.registration;
  YAML::Emitter out;
  out.SetDoublePrecision(17);  // doubles read back exactly
  out << YAML::BeginMap << YAML::Key << "registration" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "method" << YAML::Value << MethodName(o.method);
  out << YAML::Key << "crop_radius_m" << YAML::Value << o.crop_radius_m;
  out << YAML::Key << "scene_samples" << YAML::Value << o.scene_samples;
  out << YAML::Key << "model_samples" << YAML::Value << o.model_samples;
  out << YAML::Key << "icp_max_correspondence_m" << YAML::Value << o.icp.max_correspondence_m;
  out << YAML::Key << "icp_max_iterations" << YAML::Value << o.icp.max_iterations;
  out << YAML::Key << "inlier_threshold_m" << YAML::Value << o.inlier_threshold_m;
  out << YAML::Key << "sample_seed" << YAML::Value << o.sample_seed;
  out << YAML::Key << "model_cache_entries" << YAML::Value << c.model_cache_entries;
  out << YAML::Key << "tracking_error_m" << YAML::Value << o.arref_icp.tracking_error.position_m;
  out << YAML::Key << "tracking_error_deg" << YAML::Value << o.arref_icp.tracking_error.orientation_deg;
  out << YAML::EndMap << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

Result<ServerConfig> ParseServerConfig(const std::string& yaml_text, const std::string& base_dir) {
  ServerConfig c;
  try {
    ARREF_RETURN_IF_ERROR(ReadAll(YAML::Load(yaml_text), base_dir, c));
  } catch (const YAML::Exception& e) {
    return Status::InvalidArgument(std::string("YAML: ") + e.what());
  }
  return c;
}

Result<ServerConfig> LoadServerConfig(const std::string& path) {
  const std::optional<std::string> text = ReadWholeFile(path);
  if (!text) return Status::NotFound("config file " + path + " cannot be opened");
  const std::string dir = fs::absolute(fs::path(path)).parent_path().string();
  auto config = ParseServerConfig(*text, dir);
  if (!config.ok()) return config.status().WithContext(path);
  config->source = path;
  return config;
}

Result<ServerConfig> LoadDefaultServerConfig() {
  ARREF_ASSIGN_OR_RETURN(const std::string path, FindConfigFile("arref-server.yaml"));
  return LoadServerConfig(path);
}

}  // namespace arref::server
