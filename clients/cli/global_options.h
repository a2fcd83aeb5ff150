// Command-line options for the global methods' parameters (segmentation, Super4PCS, PCL 4PCS,
// FPFH + RANSAC), shared by `arref register` and `arref bench`.
#pragma once

#include <CLI/CLI.hpp>

#include "arref/pipeline/registration.h"

namespace arref::cli {

void AddGlobalMethodOptions(CLI::App& cmd, RegistrationOptions& options);

}  // namespace arref::cli
