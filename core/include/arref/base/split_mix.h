// SplitMix64 (Steele, Lea and Flood, "Fast splittable pseudorandom number generators", 2014):
// one 64-bit value into a well-mixed one. The simulators and the bench derive each random stream
// from (seed ^ purpose) through it, so that streams of one seed are independent of each other.
#pragma once

#include <cstdint>

namespace arref {

inline std::uint64_t SplitMix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

}  // namespace arref
