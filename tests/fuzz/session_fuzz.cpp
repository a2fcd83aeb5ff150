// libFuzzer target: the whole session state machine (server/session) fed from bytes. Each
// input is what one headset sends on a fresh connection, then half-closes: a Session of the
// real server code reads it through a MemoryTransport (no sockets: a system call per read
// and write cost a quarter of the time when this harness used a socket pair) in an
// in-process io_context, cut into reads of at most one TCP segment. Jobs go to a real
// JobScheduler whose runner answers at once (no registration runs: that is not what is
// fuzzed here, and it would take seconds). Every reply must be a well-formed ServerMessage
// frame, and the session must close exactly once with nothing left behind (LeakSanitizer).
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>

#include <google/protobuf/stubs/logging.h>
#include <spdlog/spdlog.h>

#include "frame_decoder.h"
#include "memory_budget.h"
#include "memory_transport.h"
#include "session.h"
#include "tracking_service.h"

namespace {

namespace net = boost::asio;
using arref::server::JobOutcome;
using arref::server::Session;
// A TCP segment's payload on Ethernet: a read delivers at most this much.
constexpr std::size_t kSegmentBytes = 1448;

struct Server {
  arref::server::ServerConfig config;
  std::unique_ptr<arref::server::RobotRegistry> robots;
  arref::server::SubscriberHub hub;
  std::atomic<bool> shutting_down{false};
  arref::server::JobScheduler jobs{1, 16, [](arref::server::Job&) {
                                     JobOutcome out;
                                     out.status = arref::Status::FailedPrecondition("fuzz harness: no registration run");
                                     return out;
                                   }};
  arref::server::TrackingService tracking{hub};
  arref::server::MemoryBudget memory{config.limits.memory_budget_bytes};
  int closed = 0;
  arref::server::ServerContext ctx{config,
                                   *robots,
                                   jobs,
                                   hub,
                                   tracking,
                                   shutting_down,
                                   memory,
                                   [](std::uint64_t) { return arref::Status::Ok(); },
                                   [this](std::uint64_t) { ++closed; },
                                   "fuzz",
                                   nullptr};

  static Server& Get() {
    static Server* server = [] {
      auto loaded = arref::server::LoadDefaultServerConfig();
      if (!loaded.ok()) std::abort();
      auto registry = arref::server::RobotRegistry::Load(loaded->robots, loaded->model_cache_entries);
      if (!registry.ok()) std::abort();
      return new Server(std::move(*loaded), std::move(*registry));
    }();
    return *server;
  }

  Server(arref::server::ServerConfig c, std::unique_ptr<arref::server::RobotRegistry> r)
      : config(std::move(c)), robots(std::move(r)) {}
};

void CheckReplies(const std::string& replies) {
  arref::wire::FrameDecoder decoder(std::uint64_t{1} << 32);
  decoder.Append(replies);
  for (;;) {
    const auto f = decoder.Next();
    if (f.kind == arref::wire::FrameDecoder::Frame::Kind::kNeedMore) break;
    if (f.kind != arref::wire::FrameDecoder::Frame::Kind::kFrame) std::abort();
    arref::wire::pb::ServerMessage m;
    if (!m.ParseFromArray(f.body.data(), static_cast<int>(f.body.size()))) std::abort();
  }
  // The transport takes each write whole, so the replies end on a frame boundary.
  if (decoder.buffered_bytes() != 0) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  spdlog::set_level(spdlog::level::off);
  google::protobuf::SetLogHandler(nullptr);  // its complaint per string with invalid UTF-8
  Server::Get();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static std::uint64_t next_id = 1;
  Server& server = Server::Get();
  const int closed_before = server.closed;
  auto replies = std::make_shared<std::string>();
  static net::io_context ioc;  // one for every input (its services are set up once), run empty
  ioc.restart();
  auto session = std::make_shared<Session>(
      std::make_unique<arref::server::MemoryTransport>(
          net::make_strand(ioc), std::string(reinterpret_cast<const char*>(data), size), kSegmentBytes, replies),
      server.ctx, next_id++);
  session->Start();
  session.reset();
  ioc.run();
  // Results of jobs still on the worker are posted to the session's executor before the job
  // leaves the scheduler: wait for them, then let their handlers run.
  while (server.jobs.running() > 0) std::this_thread::yield();
  ioc.restart();
  ioc.run();
  if (server.closed != closed_before + 1) std::abort();  // the session closed exactly once
  CheckReplies(*replies);
  return 0;
}
