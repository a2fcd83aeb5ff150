// `arref replay`: a recorded session (wire/recording.h) re-run offline, in process, with the
// server's own request handling (request_builder.h) and job runner (registration_job.h), so
// that a failure seen in the cell can be brought back to a desk. No sockets, no threads.
#pragma once

#include <functional>
#include <vector>

#include "arref/base/status.h"
#include "recording.h"
#include "server_config.h"

namespace arref::server {

struct ReplayOptions {
  // The registration defaults the recording carries (the server's when it recorded); false:
  // the given config's, to try other settings on the same session.
  bool recorded_registration = true;
};

// What the server answered, or would have, to one recorded message: a Result for each
// registration, a TrackingUpdate for each depth frame, an Error for each message it refused, a
// Pong or Subscribed.
struct ReplayedAnswer {
  std::size_t message_index = 0;  // into Recording::messages
  double t_s = 0.0;               // when that message had arrived
  wire::pb::ServerMessage message;
};

// Robots come from config.robots (by id, as the recording names them). Requests run one after
// the other in recorded order. A Result comes when the recording says the live server sent it
// (format version 2), else when its replayed run, started after the one before it, is over; a
// Cancel arriving before that answers it CANCELLED, one for no request in flight
// UNKNOWN_REQUEST. Tracking runs through the server's TrackingService, each depth frame
// processed when it arrives (none dropped). Subscribe is answered Subscribed (or UNKNOWN_ROBOT),
// Ping a Pong with the recording's server times. Answers come in the order the session would
// send them; on_answer sees each as it is made.
Result<std::vector<ReplayedAnswer>> ReplayRecording(const wire::Recording& recording, const ServerConfig& config,
                                                    const ReplayOptions& options = {},
                                                    const std::function<void(const ReplayedAnswer&)>& on_answer = {});

}  // namespace arref::server
