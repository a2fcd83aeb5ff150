#include "memory_transport.h"

#include <algorithm>
#include <cstring>

namespace arref::server {

MemoryTransport::MemoryTransport(net::any_io_executor executor, std::string input, std::size_t max_read,
                                 std::shared_ptr<std::string> output)
    : executor_(std::move(executor)), input_(std::move(input)), max_read_(std::max<std::size_t>(1, max_read)),
      output_(std::move(output)) {}

// Completions are posted, never run inside the call, as a socket's are; each holds the
// session's handler, and with it the session that owns this transport.
void MemoryTransport::AsyncHandshake(DoneHandler done) {
  net::post(executor_, [done = std::move(done)] { done(net::error::operation_not_supported); });
}

void MemoryTransport::AsyncReadSome(net::mutable_buffer buffer, IoHandler done) {
  net::post(executor_, [this, buffer, done = std::move(done)] {
    if (closed_) return done(net::error::operation_aborted, 0);
    // A socket whose receive side is shut reads end of file, as does one the client half-closed.
    if (receive_shut_ || read_ == input_.size()) return done(net::error::eof, 0);
    const std::size_t n = std::min({buffer.size(), max_read_, input_.size() - read_});
    std::memcpy(buffer.data(), input_.data() + read_, n);
    read_ += n;
    done({}, n);
  });
}

// The bytes are taken at once, as a socket with room in its send buffer takes them.
void MemoryTransport::AsyncWrite(net::const_buffer buffer, IoHandler done) {
  if (closed_) {
    net::post(executor_, [done = std::move(done)] { done(net::error::bad_descriptor, 0); });
    return;
  }
  output_->append(static_cast<const char*>(buffer.data()), buffer.size());
  net::post(executor_, [n = buffer.size(), done = std::move(done)] { done({}, n); });
}

void MemoryTransport::AsyncCloseNotify(std::chrono::milliseconds, std::function<void()> done) { done(); }

}  // namespace arref::server
