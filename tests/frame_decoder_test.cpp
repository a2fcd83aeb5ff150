// The server's frame decoder on varint-delimited streams: whole frames, frames split at every
// byte, several frames per read, and the two ways a stream is broken (huge length, bad varint).
#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <string>
#include <vector>

#include "frame_decoder.h"
#include "wire.h"

namespace arref::wire {
namespace {

using Kind = FrameDecoder::Frame::Kind;

std::string PingFrame(std::uint64_t nonce, std::size_t payload_bytes) {
  pb::ClientMessage m;
  m.mutable_ping()->set_nonce(nonce);
  m.mutable_ping()->set_payload(std::string(payload_bytes, 'x'));
  return EncodeFrame(m);
}

std::uint64_t NonceOf(std::string_view body) {
  pb::ClientMessage m;
  EXPECT_TRUE(m.ParseFromArray(body.data(), static_cast<int>(body.size())));
  return m.ping().nonce();
}

TEST(WireFrameDecoder, WholeFrame) {
  const std::string frame = PingFrame(42, 300);  // body > 127 bytes: a two-byte prefix
  FrameDecoder d(1 << 20);
  d.Append(frame);
  const auto f = d.Next();
  ASSERT_EQ(f.kind, Kind::kFrame);
  EXPECT_EQ(f.body_bytes, frame.size() - 2);
  EXPECT_EQ(f.body, std::string_view(frame).substr(2));
  EXPECT_EQ(NonceOf(f.body), 42u);
  EXPECT_EQ(d.Next().kind, Kind::kNeedMore);
  EXPECT_EQ(d.buffered_bytes(), 0u);
}

TEST(WireFrameDecoder, SplitAtEveryByteBoundary) {
  const std::string frame = PingFrame(7, 200);
  for (std::size_t split = 0; split <= frame.size(); ++split) {
    FrameDecoder d(1 << 20);
    d.Append(std::string_view(frame).substr(0, split));
    if (split < frame.size()) {
      EXPECT_EQ(d.Next().kind, Kind::kNeedMore) << "split at " << split;
      d.Append(std::string_view(frame).substr(split));
    }
    const auto f = d.Next();
    ASSERT_EQ(f.kind, Kind::kFrame) << "split at " << split;
    EXPECT_EQ(NonceOf(f.body), 7u);
    EXPECT_EQ(d.Next().kind, Kind::kNeedMore);
  }
}

TEST(WireFrameDecoder, OneByteAtATime) {
  const std::string stream = PingFrame(1, 150) + PingFrame(2, 0);
  FrameDecoder d(1 << 20);
  std::vector<std::uint64_t> nonces;
  for (char c : stream) {
    d.Append(std::string_view(&c, 1));
    for (auto f = d.Next(); f.kind == Kind::kFrame; f = d.Next()) nonces.push_back(NonceOf(f.body));
  }
  EXPECT_EQ(nonces, (std::vector<std::uint64_t>{1, 2}));
}

TEST(WireFrameDecoder, TwoFramesInOneBuffer) {
  FrameDecoder d(1 << 20);
  d.Append(PingFrame(1, 10) + PingFrame(2, 500) + PingFrame(3, 5).substr(0, 3));
  auto f = d.Next();
  ASSERT_EQ(f.kind, Kind::kFrame);
  EXPECT_EQ(NonceOf(f.body), 1u);
  f = d.Next();
  ASSERT_EQ(f.kind, Kind::kFrame);
  EXPECT_EQ(NonceOf(f.body), 2u);
  EXPECT_EQ(d.Next().kind, Kind::kNeedMore) << "the third frame is incomplete";
  EXPECT_EQ(d.buffered_bytes(), 3u);
}

TEST(WireFrameDecoder, ReadsIntoTheBufferItHandsOut) {
  const std::string frame = PingFrame(9, 20);
  FrameDecoder d(1 << 20);
  auto space = d.Buffer(64);
  ASSERT_GE(space.size(), 64u);
  std::copy(frame.begin(), frame.end(), space.begin());
  d.Commit(frame.size());
  const auto f = d.Next();
  ASSERT_EQ(f.kind, Kind::kFrame);
  EXPECT_EQ(NonceOf(f.body), 9u);
}

TEST(WireFrameDecoder, OversizedLengthIsRejectedBeforeTheBody) {
  const std::string frame = PingFrame(1, 1000);
  FrameDecoder d(100);
  d.Append(std::string_view(frame).substr(0, 2));  // only the length prefix
  const auto f = d.Next();
  ASSERT_EQ(f.kind, Kind::kTooLarge);
  EXPECT_EQ(f.body_bytes, frame.size() - 2);
  d.Append(std::string_view(frame).substr(2));
  EXPECT_EQ(d.Next().kind, Kind::kTooLarge) << "a broken stream stays broken";

  FrameDecoder exact(frame.size() - 2);  // the limit itself is allowed
  exact.Append(frame);
  EXPECT_EQ(exact.Next().kind, Kind::kFrame);

  // A prefix whose first byte already exceeds the limit is refused while it is unfinished.
  FrameDecoder early(100);
  early.Append(std::string("\xff", 1));
  EXPECT_EQ(early.Next().kind, Kind::kTooLarge);
}

TEST(WireFrameDecoder, MalformedVarintIsRejected) {
  // Ten continuation bytes: no 64-bit varint is that long.
  FrameDecoder d(std::numeric_limits<std::uint64_t>::max());
  d.Append(std::string(9, '\x80'));
  EXPECT_EQ(d.Next().kind, Kind::kNeedMore) << "nine bytes may still end";
  d.Append(std::string(1, '\x80'));
  EXPECT_EQ(d.Next().kind, Kind::kBadVarint);
  d.Append(PingFrame(1, 1));
  EXPECT_EQ(d.Next().kind, Kind::kBadVarint);
}

// Found by tests/fuzz/frame_decoder_fuzz.cpp's oracle (chunking must not change the verdict): a
// long unfinished prefix whose value passes the limit was kBadVarint when it arrived in one read
// but kTooLarge when it arrived byte by byte.
TEST(WireFrameDecoder, VerdictOnAnOverlongPrefixDoesNotDependOnTheReads) {
  const std::string prefix(11, '\xff');  // passes a limit of 100 at its first byte, never ends
  FrameDecoder whole(100);
  whole.Append(prefix);
  EXPECT_EQ(whole.Next().kind, Kind::kTooLarge);
  FrameDecoder bytewise(100);
  Kind last = Kind::kNeedMore;
  for (char c : prefix) {
    bytewise.Append(std::string(1, c));
    last = bytewise.Next().kind;
  }
  EXPECT_EQ(last, Kind::kTooLarge);
}

TEST(WireFrameDecoder, EmptyBodyIsAFrame) {
  FrameDecoder d(100);
  d.Append(std::string(1, '\0'));
  const auto f = d.Next();
  ASSERT_EQ(f.kind, Kind::kFrame);
  EXPECT_EQ(f.body_bytes, 0u);
  EXPECT_TRUE(f.body.empty());
}

TEST(WireFrameDecoder, BigBufferIsFreedOnceConsumed) {
  FrameDecoder d(1 << 22, 1024);
  d.Append(PingFrame(1, 100000));
  ASSERT_EQ(d.Next().kind, Kind::kFrame);
  EXPECT_GT(d.capacity(), 1024u);
  d.Buffer(16);
  EXPECT_LT(d.capacity(), 1024u);
}

// A frame the reader cannot take is dropped as it arrives, in pieces, without growing the
// buffer; the frames around it come through intact.
TEST(WireFrameDecoder, SkippedFrameIsDiscardedAndTheStreamGoesOn) {
  const std::string big = PingFrame(2, 200000);
  const std::string stream = PingFrame(1, 10) + big + PingFrame(3, 10);
  FrameDecoder d(1 << 20);
  d.Append(stream.substr(0, PingFrame(1, 10).size() + 3));  // frame 1 and the start of frame 2
  auto f = d.Next();
  ASSERT_EQ(f.kind, Kind::kFrame);
  EXPECT_EQ(NonceOf(f.body), 1u);
  EXPECT_EQ(d.PendingBodyBytes(), big.size() - 3) << "frame 2's three-byte prefix has arrived";
  d.SkipNext();
  EXPECT_TRUE(d.skipping());
  EXPECT_EQ(d.Next().kind, Kind::kNeedMore);
  std::size_t at = PingFrame(1, 10).size() + 3;
  while (at < stream.size()) {
    const std::size_t n = std::min<std::size_t>(4096, stream.size() - at);
    d.Append(std::string_view(stream).substr(at, n));
    at += n;
    EXPECT_LE(d.capacity(), 64u * 1024) << "skipped bytes are not kept";
    for (f = d.Next(); f.kind != Kind::kNeedMore; f = d.Next()) {
      if (f.kind == Kind::kSkipped) {
        EXPECT_EQ(f.body_bytes, big.size() - 3);
      } else {
        ASSERT_EQ(f.kind, Kind::kFrame);
        EXPECT_EQ(NonceOf(f.body), 3u);
        EXPECT_FALSE(d.skipping());
      }
    }
  }
  EXPECT_EQ(d.buffered_bytes(), 0u);
  EXPECT_EQ(d.PendingBodyBytes(), 0u);
}

TEST(WireFrameDecoder, LargerMaximumAfterAHandshake) {
  FrameDecoder d(100);
  d.Append(PingFrame(1, 50));
  EXPECT_EQ(d.Next().kind, Kind::kFrame);
  d.set_max_body_bytes(1000);
  d.Append(PingFrame(2, 500));
  const auto f = d.Next();
  ASSERT_EQ(f.kind, Kind::kFrame);
  EXPECT_EQ(NonceOf(f.body), 2u);
}

}  // namespace
}  // namespace arref::wire
