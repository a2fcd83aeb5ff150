#include "recording.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <iterator>

namespace arref::wire {

Result<std::unique_ptr<RecordingWriter>> RecordingWriter::Create(const std::string& path, pb::RecordingHeader header) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return Status::IoError("recording " + path + ": cannot create the file");
  header.set_format(kRecordingFormat);
  header.set_format_version(kRecordingFormatVersion);
  std::unique_ptr<RecordingWriter> writer(new RecordingWriter(path, std::move(out)));
  ARREF_RETURN_IF_ERROR(writer->Write(header));
  return writer;
}

Status RecordingWriter::Append(double t_s, const pb::ClientMessage& message) {
  pb::RecordedMessage recorded;
  recorded.set_t_s(t_s);
  *recorded.mutable_message() = message;
  if (recorded.message().has_hello()) recorded.mutable_message()->mutable_hello()->clear_auth_token();
  return Write(recorded);
}

Status RecordingWriter::AppendAnswer(double t_s, std::uint64_t request_id) {
  pb::RecordedMessage recorded;
  recorded.set_t_s(t_s);
  recorded.set_answered_request_id(request_id);
  return Write(recorded);
}

Status RecordingWriter::Write(const google::protobuf::MessageLite& message) {
  const std::string frame = EncodeFrame(message);
  out_.write(frame.data(), static_cast<std::streamsize>(frame.size()));
  out_.flush();
  if (!out_) return Status::IoError("recording " + path_ + ": write failed (disk full?)");
  return Status::Ok();
}

namespace {

// The body of the frame at `pos`, advancing pos; kNeedMore at a truncated tail.
struct NextFrame {
  FrameHeader::State state;
  std::string_view body;
};

NextFrame ReadFrame(const std::string& bytes, std::size_t& pos) {
  const auto* data = reinterpret_cast<const std::uint8_t*>(bytes.data()) + pos;
  const std::size_t left = bytes.size() - pos;
  const FrameHeader h = DecodeFrameHeader(data, left, left);
  if (h.state == FrameHeader::State::kTooLarge) return {FrameHeader::State::kNeedMore, {}};
  if (h.state != FrameHeader::State::kComplete) return {h.state, {}};
  const std::string_view body(bytes.data() + pos + h.header_bytes, h.body_bytes);
  pos += h.header_bytes + h.body_bytes;
  return {FrameHeader::State::kComplete, body};
}

}  // namespace

Result<Recording> ReadRecording(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::NotFound("recording " + path + ": cannot open the file");
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  Recording rec;
  std::size_t pos = 0;
  const NextFrame first = ReadFrame(bytes, pos);
  if (first.state != FrameHeader::State::kComplete ||
      !rec.header.ParseFromArray(first.body.data(), static_cast<int>(first.body.size())) ||
      rec.header.format() != kRecordingFormat)
    return Status::InvalidArgument("recording " + path + ": not an arref recording (no RecordingHeader)");
  if (rec.header.format_version() < kOldestRecordingFormatVersion ||
      rec.header.format_version() > kRecordingFormatVersion)
    return Status::InvalidArgument(fmt::format("recording {}: format version {}, this build reads versions {} to {}",
                                               path, rec.header.format_version(), kOldestRecordingFormatVersion,
                                               kRecordingFormatVersion));
  while (pos < bytes.size()) {
    const std::size_t at = pos;
    const NextFrame f = ReadFrame(bytes, pos);
    if (f.state == FrameHeader::State::kNeedMore) {
      spdlog::warn("recording {}: cut short at byte {} of {} (message {} incomplete; dropped)", path, at, bytes.size(),
                   rec.messages.size() + 1);
      break;
    }
    pb::RecordedMessage m;
    if (f.state != FrameHeader::State::kComplete || !m.ParseFromArray(f.body.data(), static_cast<int>(f.body.size())))
      return Status::InvalidArgument(fmt::format("recording {}: message {} at byte {} does not parse", path,
                                                 rec.messages.size() + 1, at));
    if (!m.has_message() && m.answered_request_id() != 0)
      rec.answered_at_s[m.answered_request_id()] = m.t_s();
    else
      rec.messages.push_back(std::move(m));
  }
  return rec;
}

}  // namespace arref::wire
