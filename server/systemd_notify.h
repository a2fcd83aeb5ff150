// sd_notify wrappers (no-ops when not started by systemd, i.e. NOTIFY_SOCKET unset).
#pragma once

#include <chrono>
#include <optional>
#include <string>

namespace arref::server {

void NotifySystemd(const std::string& state);  // e.g. "READY=1", "STOPPING=1"
// Half the watchdog period systemd asked for (WATCHDOG_USEC), if it asked.
std::optional<std::chrono::microseconds> WatchdogInterval();

}  // namespace arref::server
