#include "frame_decoder.h"

#include <algorithm>
#include <cstring>

#include "wire.h"

namespace arref::wire {

FrameDecoder::FrameDecoder(std::uint64_t max_body_bytes, std::size_t shrink_above_bytes)
    : max_body_bytes_(max_body_bytes), shrink_above_bytes_(shrink_above_bytes) {}

std::span<std::uint8_t> FrameDecoder::Buffer(std::size_t min_bytes) {
  if (begin_ == end_) {
    begin_ = end_ = 0;
    // One huge message must not pin its buffer for the rest of a long session.
    if (buf_.size() > shrink_above_bytes_) buf_ = std::vector<std::uint8_t>();
  } else if (begin_ > 0) {
    std::memmove(buf_.data(), buf_.data() + begin_, end_ - begin_);
    end_ -= begin_;
    begin_ = 0;
  }
  if (buf_.size() - end_ < min_bytes) {
    // Once a frame's length is known, room for all of it is made at once: growing by doubling
    // would hold up to twice a large frame.
    const FrameHeader h = DecodeFrameHeader(buf_.data() + begin_, end_ - begin_, max_body_bytes_);
    if (h.state == FrameHeader::State::kComplete && skip_left_ == 0)
      buf_.reserve(std::max<std::size_t>(end_ + min_bytes, h.header_bytes + h.body_bytes + min_bytes));
    buf_.resize(end_ + min_bytes);
  }
  return {buf_.data() + end_, buf_.size() - end_};
}

void FrameDecoder::Commit(std::size_t n) { end_ += n; }

void FrameDecoder::Append(std::string_view bytes) {
  const auto space = Buffer(bytes.size());
  if (!bytes.empty()) std::memcpy(space.data(), bytes.data(), bytes.size());
  Commit(bytes.size());
}

std::uint64_t FrameDecoder::PendingBodyBytes() const {
  if (error_.kind != Frame::Kind::kNeedMore || skip_left_ > 0) return 0;
  const FrameHeader h = DecodeFrameHeader(buf_.data() + begin_, end_ - begin_, max_body_bytes_);
  return h.state == FrameHeader::State::kComplete ? h.body_bytes : 0;
}

void FrameDecoder::SkipNext() {
  if (error_.kind != Frame::Kind::kNeedMore || skip_left_ > 0) return;
  const FrameHeader h = DecodeFrameHeader(buf_.data() + begin_, end_ - begin_, max_body_bytes_);
  if (h.state != FrameHeader::State::kComplete) return;
  skip_left_ = h.header_bytes + h.body_bytes;
  skip_body_ = h.body_bytes;
}

FrameDecoder::Frame FrameDecoder::Next() {
  if (error_.kind != Frame::Kind::kNeedMore) return error_;
  if (skip_left_ > 0) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(skip_left_, end_ - begin_));
    begin_ += n;
    skip_left_ -= n;
    if (skip_left_ > 0) return Frame{};
    return Frame{.kind = Frame::Kind::kSkipped, .body = {}, .body_bytes = skip_body_};
  }
  const FrameHeader h = DecodeFrameHeader(buf_.data() + begin_, end_ - begin_, max_body_bytes_);
  Frame f;
  switch (h.state) {
    case FrameHeader::State::kNeedMore: return f;
    case FrameHeader::State::kTooLarge:
      error_.kind = Frame::Kind::kTooLarge;
      error_.body_bytes = h.body_bytes;
      return error_;
    case FrameHeader::State::kBadVarint:
      error_.kind = Frame::Kind::kBadVarint;
      return error_;
    case FrameHeader::State::kComplete: break;
  }
  const std::size_t frame_bytes = h.header_bytes + h.body_bytes;  // body_bytes <= max, so no overflow
  if (end_ - begin_ < frame_bytes) return f;
  f.kind = Frame::Kind::kFrame;
  f.body_bytes = h.body_bytes;
  f.body = std::string_view(reinterpret_cast<const char*>(buf_.data() + begin_ + h.header_bytes), h.body_bytes);
  begin_ += frame_bytes;
  return f;
}

}  // namespace arref::wire
