// arref-server configuration: YAML file (config/arref-server.yaml) plus command-line overrides.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "arref/pipeline/pipeline.h"
#include "arref/robot/robot_model.h"
#include "arref/base/status.h"

namespace arref::server {

// A robot the server can register. Clients name it by id only; files stay on the server.
struct RobotConfig {
  std::string id;
  std::string urdf;                       // absolute path (resolved from "builtin" or relative)
  std::vector<std::string> package_path;  // absolute folders for package:// URIs
  JointValues default_joints;             // unnamed joints: 0 (clamped into limits)
};

struct ServerLimits {
  std::size_t max_message_bytes = 16u << 20;      // one incoming frame
  std::size_t max_sessions = 64;                  // connections past Hello
  std::size_t max_pending_connections = 128;      // connections still owing Hello (the oldest is dropped)
  std::size_t max_connections_per_peer = 16;      // from one IP address, pending and sessions
  std::size_t max_surfaces_per_session = 4000;
  std::size_t max_vertices_per_session = 4'000'000;
  std::size_t max_triangles_per_session = 8'000'000;
  std::size_t max_mesh_bytes_per_session = 128u << 20;  // vertices, triangles and per-surface records
  // Server-wide admission budget for meshes, large frames and jobs (memory_budget.h). The
  // default fits a 2 GiB unit (MemoryMax=2G) with room for the robot models and the allocator.
  std::size_t memory_budget_bytes = 1024u << 20;
  std::size_t max_requests_per_session = 8;       // accepted and not yet answered
  std::size_t max_map_triangles = 1'000'000;      // a request with no seed searches the whole map: at most this
  std::size_t max_send_queue_bytes = 8u << 20;    // unsent replies before the session is dropped
  std::size_t max_send_queue_messages = 4096;
};

// TLS on the listening socket (config section `tls`). Without a certificate the server speaks
// plain TCP, as it always did; files are PEM and are read once, at startup.
struct TlsConfig {
  std::string certificate_chain;  // the server's certificate, then any intermediates
  std::string private_key;        // unencrypted (the daemon has no one to ask for a passphrase)
  std::string client_ca;          // non-empty: every client must present a certificate this CA signed
  bool enabled() const { return !certificate_chain.empty() || !private_key.empty(); }
};

struct ServerConfig {
  std::string address = "0.0.0.0";
  std::uint16_t port = 7311;
  int io_threads = 1;
  int workers = 2;
  std::size_t queue_size = 16;
  double idle_timeout_s = 120.0;   // no bytes from the client and nothing in flight
  double hello_timeout_s = 5.0;    // a connection must complete Hello within this
  double frame_timeout_s = 30.0;   // a frame, once its first byte arrived, must complete within this
  double send_timeout_s = 30.0;    // one write may take this long before the session is dropped
  double shutdown_grace_s = 30.0;  // running jobs may finish within this on SIGTERM
  std::string auth_token;          // empty: no token required
  // The token crosses the network in clear text when TLS is off: refused on a non-loopback
  // address unless this is set (ClearTextTokenRisk).
  bool allow_plaintext_token = false;
  std::string log_level = "info";
  // Non-empty: every session is recorded to a file in this folder (wire/recording.h), its
  // client messages with their arrival times; never the auth token.
  std::string record_dir;
  TlsConfig tls;
  ServerLimits limits;
  RegistrationOptions registration;
  std::size_t model_cache_entries = 32;
  std::vector<RobotConfig> robots;
  std::string source;  // where the config came from, for logs
};

// Parses YAML text; relative paths resolve against base_dir. Unknown keys are errors (a typo
// must not silently fall back to a default).
Result<ServerConfig> ParseServerConfig(const std::string& yaml_text, const std::string& base_dir);
Result<ServerConfig> LoadServerConfig(const std::string& path);
// The built-in default: config/arref-server.yaml found via FindConfigFile.
Result<ServerConfig> LoadDefaultServerConfig();
Status ValidateServerConfig(const ServerConfig& config);
// Why the configured auth token would cross the network in clear text (a token, no TLS, a
// listen address that is not loopback), or "" when it would not. Validation refuses such a
// config unless server.allow_plaintext_token is set; the server then warns with this text.
std::string ClearTextTokenRisk(const ServerConfig& config);

// The "registration" section of a config with this config's values (what a recording carries,
// so that a replay registers as the server did). ParseServerConfig reads it back.
std::string RegistrationYaml(const ServerConfig& config);

}  // namespace arref::server
