// Splits a byte stream into varint-delimited frames (protobuf's delimited format), for a
// reader that receives arbitrary chunks: bytes are written into Buffer(), Commit()ted, and
// Next() hands out complete frame bodies one by one. No protobuf or I/O here.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

namespace arref::wire {

class FrameDecoder {
 public:
  // Frames whose declared body exceeds max_body_bytes are refused before they are buffered.
  // A buffer that grew past shrink_above_bytes is freed once it has been fully consumed.
  explicit FrameDecoder(std::uint64_t max_body_bytes, std::size_t shrink_above_bytes = 256 * 1024);

  // Free space for at least min_bytes more bytes (moves unconsumed bytes to the front, so it
  // invalidates the body of the last frame).
  std::span<std::uint8_t> Buffer(std::size_t min_bytes);
  // The first n bytes of the last Buffer() now hold data.
  void Commit(std::size_t n);
  // Buffer + copy + Commit, for callers that already hold the bytes.
  void Append(std::string_view bytes);

  struct Frame {
    enum class Kind { kNeedMore, kFrame, kTooLarge, kBadVarint, kSkipped } kind = Kind::kNeedMore;
    std::string_view body;         // kFrame: valid until the next Buffer/Append
    std::uint64_t body_bytes = 0;  // kFrame, kTooLarge, kSkipped: the declared length
  };
  // The next complete frame, or why there is none. kTooLarge and kBadVarint are final: the
  // stream cannot be resynchronised, so they are returned again on every later call.
  Frame Next();

  // The declared body length of the next frame once its length prefix has arrived (and is
  // within the maximum), else 0.
  std::uint64_t PendingBodyBytes() const;
  // Drops the next frame, whose prefix has arrived, without buffering it: its bytes are
  // discarded as they come, and Next() returns kSkipped once the last one has passed. For a
  // frame the reader cannot take now (e.g. over a memory budget) without losing the stream.
  void SkipNext();
  // The largest frame body accepted from now on (e.g. larger after a handshake).
  void set_max_body_bytes(std::uint64_t max_body_bytes) { max_body_bytes_ = max_body_bytes; }
  bool skipping() const { return skip_left_ > 0; }

  std::size_t buffered_bytes() const { return end_ - begin_; }
  std::size_t capacity() const { return buf_.size(); }

 private:
  std::uint64_t max_body_bytes_;
  std::size_t shrink_above_bytes_;
  std::vector<std::uint8_t> buf_;
  std::size_t begin_ = 0;  // first unconsumed byte
  std::size_t end_ = 0;    // one past the last received byte
  Frame error_;            // set once the stream is broken
  std::uint64_t skip_left_ = 0;   // bytes of a skipped frame still to discard
  std::uint64_t skip_body_ = 0;   // its declared body length
};

}  // namespace arref::wire
