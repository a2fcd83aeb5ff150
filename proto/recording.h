// Session recordings (arref.proto, "recordings"): a RecordingHeader, then one RecordedMessage
// per client message (and one answer record per Result sent), each varint-delimited like the
// wire. The writer clears Hello.auth_token itself, so no caller can leak a token into a file.
#pragma once

#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "arref/base/status.h"
#include "wire.h"

namespace arref::wire {

inline constexpr char kRecordingFormat[] = "arref-recording";
inline constexpr std::uint32_t kRecordingFormatVersion = 2;
inline constexpr std::uint32_t kOldestRecordingFormatVersion = 1;  // still read

class RecordingWriter {
 public:
  // Creates (truncates) the file and writes the header (format and version are filled in).
  static Result<std::unique_ptr<RecordingWriter>> Create(const std::string& path, pb::RecordingHeader header);
  // Appends one message received t_s after the connection was accepted, and flushes, so that a
  // crash loses nothing already received.
  Status Append(double t_s, const pb::ClientMessage& message);
  // Records that the Result of `request_id` was sent t_s after the connection was accepted.
  Status AppendAnswer(double t_s, std::uint64_t request_id);
  const std::string& path() const { return path_; }

 private:
  RecordingWriter(std::string path, std::ofstream out) : path_(std::move(path)), out_(std::move(out)) {}
  Status Write(const google::protobuf::MessageLite& message);
  std::string path_;
  std::ofstream out_;
};

struct Recording {
  pb::RecordingHeader header;
  std::vector<pb::RecordedMessage> messages;  // the client's, in arrival order
  std::map<std::uint64_t, double> answered_at_s;  // request id -> when its Result was sent (version 2)
};

// The whole file. Errors name the file and the byte or message where it broke (a wrong format,
// a truncated frame, bytes that do not parse); a file cut short after its last whole message
// (a server killed mid-write) loses only that message, with a warning in the log.
Result<Recording> ReadRecording(const std::string& path);

}  // namespace arref::wire
