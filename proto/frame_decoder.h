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
    enum class Kind { kNeedMore, kFrame, kTooLarge, kBadVarint } kind = Kind::kNeedMore;
    std::string_view body;         // kFrame: valid until the next Buffer/Append
    std::uint64_t body_bytes = 0;  // kFrame, kTooLarge: the declared length
  };
  // The next complete frame, or why there is none. kTooLarge and kBadVarint are final: the
  // stream cannot be resynchronised, so they are returned again on every later call.
  Frame Next();

  std::size_t buffered_bytes() const { return end_ - begin_; }
  std::size_t capacity() const { return buf_.size(); }

 private:
  std::uint64_t max_body_bytes_;
  std::size_t shrink_above_bytes_;
  std::vector<std::uint8_t> buf_;
  std::size_t begin_ = 0;  // first unconsumed byte
  std::size_t end_ = 0;    // one past the last received byte
  Frame error_;            // set once the stream is broken
};

}  // namespace arref::wire
