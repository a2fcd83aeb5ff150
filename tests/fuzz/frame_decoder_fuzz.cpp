// libFuzzer target: the server's frame decoder (proto/frame_decoder) on an arbitrary byte
// stream cut into arbitrary reads. Checks that chunking never changes what comes out: the
// frames and the final state equal those of the whole stream decoded at once.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>
#include <vector>

#include "frame_decoder.h"

namespace {

using arref::wire::FrameDecoder;
using Kind = FrameDecoder::Frame::Kind;

struct Decoded {
  std::vector<std::string> bodies;
  Kind last = Kind::kNeedMore;
  std::uint64_t last_bytes = 0;
};

void Drain(FrameDecoder& d, Decoded* out) {
  for (;;) {
    const auto f = d.Next();
    if (f.kind == Kind::kFrame) {
      if (f.body.size() != f.body_bytes) std::abort();
      out->bodies.emplace_back(f.body);
      continue;
    }
    out->last = f.kind;
    out->last_bytes = f.body_bytes;
    return;
  }
}

}  // namespace

// Input: byte 0 picks the body limit, byte 1 seeds the read sizes, the rest is the stream.
extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  const std::uint64_t max_body = std::uint64_t{data[0]} * 37;
  std::uint32_t rng = data[1] * 2654435761u + 1;
  const std::string_view stream(reinterpret_cast<const char*>(data + 2), size - 2);

  Decoded whole;
  {
    FrameDecoder d(max_body, 64);
    d.Append(stream);
    Drain(d, &whole);
  }
  Decoded chunked;
  FrameDecoder d(max_body, 64);
  for (std::size_t at = 0; at < stream.size();) {
    rng = rng * 1103515245u + 12345u;
    const std::size_t n = std::min<std::size_t>(1 + (rng >> 16) % 97, stream.size() - at);
    // Half the reads go through Buffer/Commit as the session does, half through Append.
    if (rng & 1) {
      const auto space = d.Buffer(n);
      if (space.size() < n) std::abort();
      std::copy_n(stream.data() + at, n, space.data());
      d.Commit(n);
    } else {
      d.Append(stream.substr(at, n));
    }
    at += n;
    Drain(d, &chunked);
    if (chunked.last != Kind::kNeedMore) break;  // final: nothing more would come out
  }
  if (chunked.last == Kind::kNeedMore) Drain(d, &chunked);
  if (chunked.bodies != whole.bodies || chunked.last != whole.last) std::abort();
  if (whole.last == Kind::kTooLarge && whole.last_bytes <= max_body) std::abort();
  return 0;
}
