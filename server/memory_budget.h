// The server-wide memory budget (limits.memory_budget_bytes): admission control for the memory
// that clients make the server hold, so that no mix of sessions can push the process past its
// unit's MemoryMax. Charged: every session's surfaces, large frames while they are received and
// parsed, and every accepted job (its scene snapshot and an estimate of its working memory).
// Not charged: the fixed part (robot models and their cache, threads, code), which the budget's
// default leaves room for. Thread-safe; no Asio or protobuf here.
#pragma once

#include <atomic>
#include <cstddef>
#include <string>
#include <string_view>

#include "arref/base/geometry.h"
#include "arref/base/status.h"

namespace arref::server {

class MemoryBudget {
 public:
  // Bytes held against the budget until it is destroyed (or moved from). Empty by default.
  class Reservation {
   public:
    Reservation() = default;
    Reservation(Reservation&& other) noexcept;
    Reservation& operator=(Reservation&& other) noexcept;
    Reservation(const Reservation&) = delete;
    Reservation& operator=(const Reservation&) = delete;
    ~Reservation();
    std::size_t bytes() const { return bytes_; }
    void Release();

   private:
    friend class MemoryBudget;
    Reservation(MemoryBudget* budget, std::size_t bytes) : budget_(budget), bytes_(bytes) {}
    MemoryBudget* budget_ = nullptr;
    std::size_t bytes_ = 0;
  };

  explicit MemoryBudget(std::size_t limit_bytes) : limit_(limit_bytes) {}
  MemoryBudget(const MemoryBudget&) = delete;
  MemoryBudget& operator=(const MemoryBudget&) = delete;

  // The bytes, or kResourceExhausted naming `what`, the budget and what it holds now.
  Result<Reservation> Reserve(std::size_t bytes, std::string_view what);

  std::size_t used() const { return used_.load(); }
  std::size_t limit() const { return limit_; }

 private:
  const std::size_t limit_;
  std::atomic<std::size_t> used_{0};
};

// What the server holds for a mesh of this many vertices and triangles (also what a session's
// limits.max_mesh_bytes_per_session counts).
std::size_t MeshBytes(std::size_t vertices, std::size_t triangles);
inline std::size_t MeshBytes(const TriangleMesh& mesh) { return MeshBytes(mesh.vertices.size(), mesh.triangles.size()); }

// A job's charge: its scene snapshot, the crop and samples it makes and the method's working
// set. An upper estimate (memory_budget.cpp says what it was measured against). The robot
// models and their cache (server.model_cache_entries) are the server's fixed part.
std::size_t JobBytes(std::size_t scene_bytes, std::size_t scene_samples);

// A received frame's charge: the bytes themselves and the parsed message, whose packed varints
// may take up to four times their wire size in memory.
constexpr std::size_t kFrameExpansion = 5;

std::string MiB(std::size_t bytes);  // "12.3 MiB", for messages

}  // namespace arref::server
