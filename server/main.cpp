// arref-server: registration service for HoloLens headsets (see server.h, config/arref-server.yaml).
#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <malloc.h>
#include <spdlog/spdlog.h>

#include <optional>

#include "server.h"
#include "server_config.h"

namespace {

using arref::server::ServerConfig;

struct Overrides {
  std::string config_path;
  std::optional<std::string> address;
  std::optional<int> port;
  std::optional<int> workers;
  std::optional<int> io_threads;
  std::optional<std::size_t> queue_size;
  std::optional<std::size_t> max_sessions;
  std::optional<double> idle_timeout_s;
  std::optional<double> shutdown_grace_s;
  std::optional<std::string> log_level;
  bool check_config = false;
};

void AddFlags(CLI::App& app, Overrides& o) {
  app.add_option("--config", o.config_path, "YAML config (default: the built-in config/arref-server.yaml)");
  app.add_option("--address", o.address, "Listen address, e.g. 0.0.0.0 or 127.0.0.1");
  app.add_option("--port", o.port, "Listen port; 0 picks a free port (printed as 'listening on ADDR:PORT')")
      ->check(CLI::Range(0, 65535));
  app.add_option("--workers", o.workers, "Registration worker threads")->check(CLI::Range(1, 256));
  app.add_option("--io-threads", o.io_threads, "Network threads")->check(CLI::Range(1, 64));
  app.add_option("--queue-size", o.queue_size, "Jobs that may wait for a worker before BUSY");
  app.add_option("--max-sessions", o.max_sessions, "Concurrent connections");
  app.add_option("--idle-timeout", o.idle_timeout_s, "Close sessions silent for this long, s");
  app.add_option("--shutdown-grace", o.shutdown_grace_s, "On SIGTERM, running jobs may finish within this, s");
  app.add_option("--log-level", o.log_level, "trace, debug, info, warn, error, off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "critical", "off"}));
  app.add_flag("--check-config", o.check_config, "Load the config and robots, then exit");
}

void Apply(const Overrides& o, ServerConfig& c) {
  if (o.address) c.address = *o.address;
  if (o.port) c.port = static_cast<std::uint16_t>(*o.port);
  if (o.workers) c.workers = *o.workers;
  if (o.io_threads) c.io_threads = *o.io_threads;
  if (o.queue_size) c.queue_size = *o.queue_size;
  if (o.max_sessions) c.limits.max_sessions = *o.max_sessions;
  if (o.idle_timeout_s) c.idle_timeout_s = *o.idle_timeout_s;
  if (o.shutdown_grace_s) c.shutdown_grace_s = *o.shutdown_grace_s;
  if (o.log_level) c.log_level = *o.log_level;
}

}  // namespace

int main(int argc, char** argv) {
  // Blocks of 1 MiB and more (frames, surfaces, scene snapshots) go straight to the OS and back
  // when freed, so the process's RSS follows what the memory budget holds; glibc's adaptive
  // threshold would otherwise keep freed frames resident.
  mallopt(M_MMAP_THRESHOLD, 1 << 20);
  CLI::App app{"arref-server: registers robot models to HoloLens spatial meshes for connected headsets"};
  Overrides overrides;
  AddFlags(app, overrides);
  CLI11_PARSE(app, argc, argv);

  // Logs go to stderr (journald under systemd); stdout carries only the listening line.
  spdlog::set_default_logger(spdlog::stderr_color_mt("arref-server"));
  auto config = overrides.config_path.empty() ? arref::server::LoadDefaultServerConfig()
                                              : arref::server::LoadServerConfig(overrides.config_path);
  if (!config.ok()) {
    spdlog::error("config: {}", config.status().ToString());
    return 2;
  }
  Apply(overrides, *config);
  spdlog::set_level(spdlog::level::from_str(config->log_level));
  spdlog::info("config: {}", config->source);
  auto server = arref::server::Server::Create(std::move(*config));
  if (!server.ok()) {
    spdlog::error("{}", server.status().ToString());
    return 2;
  }
  if (overrides.check_config) return 0;
  const arref::Status status = (*server)->Run();
  if (!status.ok()) {
    spdlog::error("{}", status.ToString());
    return 1;
  }
  return 0;
}
