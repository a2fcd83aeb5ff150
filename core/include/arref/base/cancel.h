// CancelToken: how a caller asks a running registration to stop. The pipeline and the long
// steps inside it (each ICP iteration, the refit) poll it and return Status::Cancelled; it is
// never an exception, so no error crosses core's API as one.
#pragma once

#include <atomic>

namespace arref {

class CancelToken {
 public:
  void Cancel() { cancelled_.store(true, std::memory_order_relaxed); }
  bool cancelled() const { return cancelled_.load(std::memory_order_relaxed); }

 private:
  std::atomic<bool> cancelled_{false};
};

// A null token never cancels: most callers (tests, the command line) pass none.
inline bool Cancelled(const CancelToken* token) { return token && token->cancelled(); }

}  // namespace arref
