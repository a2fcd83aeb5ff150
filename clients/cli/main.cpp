// arref: replay captured or simulated headset meshes, register robots, compare methods.
#include <spdlog/cfg/env.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "cli_common.h"
#include "commands.h"

int main(int argc, char** argv) {
  // Logs go to stderr so that --json output on stdout stays machine-readable.
  spdlog::set_default_logger(spdlog::stderr_color_mt("arref"));
  spdlog::set_pattern("%^[%l]%$ %v");
  spdlog::cfg::load_env_levels();  // SPDLOG_LEVEL=debug for details

  CLI::App app{"arref: reference a robot arm to a head-mounted display's spatial mesh"};
  app.require_subcommand(1);
  std::string log_level;
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off (default: SPDLOG_LEVEL or info)")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}));
  app.parse_complete_callback([&] {
    if (!log_level.empty()) spdlog::set_level(spdlog::level::from_str(log_level));
  });

  int exit_code = arref::cli::kExitOk;
  arref::cli::AddSimulateCommand(app, &exit_code);
  arref::cli::AddRegisterCommand(app, &exit_code);
  arref::cli::AddDemoCommand(app, &exit_code);
  arref::cli::AddBenchCommand(app, &exit_code);
  arref::cli::AddReplayCommand(app, &exit_code);
  arref::cli::AddSimulateTrackCommand(app, &exit_code);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : arref::cli::kExitUsage;
  }
  return exit_code;
}
