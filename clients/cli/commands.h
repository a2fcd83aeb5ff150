// The `arref` subcommands. Each registers itself on the app and writes its exit code.
#pragma once

#include <CLI/CLI.hpp>

namespace arref::cli {

void AddSimulateCommand(CLI::App& app, int* exit_code);
void AddRegisterCommand(CLI::App& app, int* exit_code);
void AddDemoCommand(CLI::App& app, int* exit_code);
void AddBenchCommand(CLI::App& app, int* exit_code);
void AddReplayCommand(CLI::App& app, int* exit_code);
void AddSimulateTrackCommand(CLI::App& app, int* exit_code);

}  // namespace arref::cli
