// One registration job run to its outcome on the calling thread: the server's workers run it,
// and so does `arref replay` (replay.h), so that a replay registers exactly as the server did.
#pragma once

#include "job_scheduler.h"
#include "robot_registry.h"

namespace arref::server {

// Honours job.cancel; reports progress through job.on_progress when set.
JobOutcome RunRegistrationJob(Job& job, RobotRegistry& robots);

}  // namespace arref::server
