#include "server.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <csignal>
#include <iostream>
#include <map>
#include <mutex>
#include <thread>

#include "robot_registry.h"
#include "session.h"
#include "systemd_notify.h"

namespace arref::server {
namespace {

using Clock = std::chrono::steady_clock;
constexpr auto kPollInterval = std::chrono::milliseconds(50);
constexpr auto kCancelGrace = std::chrono::seconds(10);   // after cancelling overdue jobs
constexpr auto kFlushGrace = std::chrono::seconds(5);     // for sessions to send their last bytes

// Thrown from the progress callback to stop a running job at a stage boundary.
struct JobCancelled {};

double MsSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

JobOutcome RunRegistrationJob(Job& job, RobotRegistry& robots) {
  JobOutcome out;
  out.queue_ms = MsSince(job.accepted_at);
  const auto start = Clock::now();
  auto check_cancel = [&job] {
    if (job.cancel_requested) throw JobCancelled{};
  };
  try {
    check_cancel();
    if (job.on_progress) job.on_progress("model", 0.0);
    const ServedRobot* robot = robots.Find(job.robot_id);
    auto model = robots.Model(*robot, job.joints, job.options.model_samples, job.options.sample_seed);
    if (!model.ok()) {
      out.status = model.status().WithContext("robot model");
      return out;
    }
    check_cancel();
    const ProgressFn progress = [&](std::string_view stage, double fraction) {
      check_cancel();
      if (job.on_progress) job.on_progress(stage, 0.05 + 0.95 * fraction);
    };
    auto report = RegisterScene(**model, job.scene_world, job.T_world_seed, job.options, progress);
    if (report.ok())
      out.report = std::move(*report);
    else
      out.status = report.status();
  } catch (const JobCancelled&) {
    out.status = Status::Cancelled("cancelled while running");
  }
  out.run_ms = MsSince(start);
  return out;
}

}  // namespace

struct Server::Impl {
  explicit Impl(ServerConfig c, std::unique_ptr<RobotRegistry> r)
      : config(std::move(c)),
        robots(std::move(r)),
        jobs(static_cast<std::size_t>(config.workers), config.queue_size,
             [this](Job& job) { return RunRegistrationJob(job, *robots); }),
        ctx{config, *robots, jobs, hub, shutting_down, [this](std::uint64_t id) { OnSessionClosed(id); },
            ARREF_VERSION},
        strand(net::make_strand(ioc)),
        acceptor(strand),
        signals(strand, SIGINT, SIGTERM),
        watchdog_timer(strand),
        shutdown_timer(strand) {}

  ~Impl() {
    for (auto& job : jobs.CloseQueue()) FinishCancelled(*job, "server stopping");
    jobs.CancelAllRunning();
    jobs.Join();
  }

  Status Listen();
  void Accept();
  void OnAccept(const boost::system::error_code& ec, tcp::socket socket);
  void OnSessionClosed(std::uint64_t id);
  std::vector<std::shared_ptr<Session>> SessionsSnapshot();
  void ArmWatchdog(std::chrono::microseconds interval);
  void BeginShutdown(const std::string& why);
  void WaitForRunningJobs(Clock::time_point deadline, bool cancelled);
  void WaitForSessionsClosed(Clock::time_point deadline);

  ServerConfig config;
  std::unique_ptr<RobotRegistry> robots;
  SubscriberHub hub;
  std::atomic<bool> shutting_down{false};
  JobScheduler jobs;
  ServerContext ctx;
  // Declared after everything sessions refer to, so handlers die first.
  net::io_context ioc;
  net::strand<net::io_context::executor_type> strand;  // acceptor, signals, timers
  tcp::acceptor acceptor;
  net::signal_set signals;
  net::steady_timer watchdog_timer;
  net::steady_timer shutdown_timer;
  std::atomic<std::uint16_t> port{0};
  std::mutex sessions_mu;
  std::map<std::uint64_t, std::shared_ptr<Session>> sessions;
  std::uint64_t next_session_id = 1;
};

Status Server::Impl::Listen() {
  boost::system::error_code ec;
  const auto address = net::ip::make_address(config.address, ec);
  if (ec) return Status::InvalidArgument("listen address '" + config.address + "': " + ec.message());
  const tcp::endpoint endpoint(address, config.port);
  acceptor.open(endpoint.protocol(), ec);
  if (!ec) acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) acceptor.bind(endpoint, ec);
  if (!ec) acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec)
    return Status(StatusCode::kUnavailable,
                  fmt::format("cannot listen on {}:{}: {}", config.address, config.port, ec.message()));
  port = acceptor.local_endpoint().port();
  return Status::Ok();
}

void Server::Impl::Accept() {
  acceptor.async_accept(net::make_strand(ioc), [this](const boost::system::error_code& ec, tcp::socket socket) {
    OnAccept(ec, std::move(socket));
  });
}

void Server::Impl::OnAccept(const boost::system::error_code& ec, tcp::socket socket) {
  if (ec == net::error::operation_aborted || !acceptor.is_open()) return;
  if (ec) {
    spdlog::warn("accept failed: {}", ec.message());  // e.g. out of file descriptors: keep serving
    Accept();
    return;
  }
  boost::system::error_code ignored;
  socket.set_option(tcp::no_delay(true), ignored);  // small replies (Accepted, Progress) go out at once
  std::shared_ptr<Session> session;
  bool full = false;
  {
    std::lock_guard lock(sessions_mu);
    full = sessions.size() >= config.limits.max_sessions;
    session = std::make_shared<Session>(std::move(socket), ctx, next_session_id++);
    if (!full) sessions[session->id()] = session;
  }
  if (full)
    session->Reject(wire::pb::ERROR_CODE_LIMIT_EXCEEDED,
                    fmt::format("too many sessions: {} connected, limit {} (limits.max_sessions)",
                                config.limits.max_sessions, config.limits.max_sessions));
  else
    session->Start();
  Accept();
}

void Server::Impl::OnSessionClosed(std::uint64_t id) {
  std::lock_guard lock(sessions_mu);
  sessions.erase(id);
}

std::vector<std::shared_ptr<Session>> Server::Impl::SessionsSnapshot() {
  std::lock_guard lock(sessions_mu);
  std::vector<std::shared_ptr<Session>> out;
  for (auto& [id, s] : sessions) out.push_back(s);
  return out;
}

void Server::Impl::ArmWatchdog(std::chrono::microseconds interval) {
  watchdog_timer.expires_after(interval);
  watchdog_timer.async_wait([this, interval](const boost::system::error_code& ec) {
    if (ec) return;
    NotifySystemd("WATCHDOG=1");
    ArmWatchdog(interval);
  });
}

void Server::Impl::BeginShutdown(const std::string& why) {
  if (shutting_down.exchange(true)) {
    spdlog::warn("{} again: cancelling running jobs now", why);
    jobs.CancelAllRunning();
    return;
  }
  NotifySystemd("STOPPING=1");
  boost::system::error_code ignored;
  acceptor.close(ignored);
  const auto queued = jobs.CloseQueue();
  spdlog::info("shutting down ({}): not accepting; {} queued jobs cancelled; {} running get {} s to finish", why,
               queued.size(), jobs.running(), config.shutdown_grace_s);
  for (const auto& job : queued) FinishCancelled(*job, "server shutting down before the job started");
  for (const auto& s : SessionsSnapshot()) s->NotifyShutdown(config.shutdown_grace_s);
  const auto grace = std::chrono::milliseconds(static_cast<long long>(config.shutdown_grace_s * 1000));
  WaitForRunningJobs(Clock::now() + grace, false);
}

void Server::Impl::WaitForRunningJobs(Clock::time_point deadline, bool cancelled) {
  const bool overdue = Clock::now() >= deadline;
  if (jobs.running() > 0 && !(overdue && cancelled)) {
    if (overdue) {
      spdlog::warn("{} jobs still running after the grace period: cancelling them", jobs.running());
      jobs.CancelAllRunning();
      deadline = Clock::now() + kCancelGrace;
      cancelled = true;
    }
    shutdown_timer.expires_after(kPollInterval);
    shutdown_timer.async_wait([this, deadline, cancelled](const boost::system::error_code& ec) {
      if (!ec) WaitForRunningJobs(deadline, cancelled);
    });
    return;
  }
  if (jobs.running() > 0) spdlog::error("{} jobs did not stop; their sessions close without a result", jobs.running());
  // Every result has been posted to its session before its job left `running`, so a close
  // posted now is queued behind it.
  for (const auto& s : SessionsSnapshot()) s->CloseGracefully("server shutting down");
  WaitForSessionsClosed(Clock::now() + kFlushGrace);
}

void Server::Impl::WaitForSessionsClosed(Clock::time_point deadline) {
  std::size_t open = 0;
  {
    std::lock_guard lock(sessions_mu);
    open = sessions.size();
  }
  if (open > 0 && Clock::now() < deadline) {
    shutdown_timer.expires_after(kPollInterval);
    shutdown_timer.async_wait([this, deadline](const boost::system::error_code& ec) {
      if (!ec) WaitForSessionsClosed(deadline);
    });
    return;
  }
  if (open > 0) spdlog::warn("{} sessions did not close in time", open);
  signals.cancel();
  watchdog_timer.cancel();
  ioc.stop();
}

// ---------------------------------------------------------------- Server

Server::Server(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Server::~Server() = default;

Result<std::unique_ptr<Server>> Server::Create(ServerConfig config) {
  ARREF_RETURN_IF_ERROR(ValidateServerConfig(config));
  auto robots = RobotRegistry::Load(config.robots, config.model_cache_entries);
  if (!robots.ok()) return robots.status();
  auto impl = std::make_unique<Impl>(std::move(config), std::move(*robots));
  return std::unique_ptr<Server>(new Server(std::move(impl)));
}

Status Server::Run() {
  Impl& s = *impl_;
  ARREF_RETURN_IF_ERROR(s.Listen());
  // The one machine-readable line on stdout (logs go to stderr): tests and scripts read the port.
  std::cout << "listening on " << s.config.address << ":" << s.port << std::endl;
  spdlog::info("arref-server {} listening on {}:{} ({} workers, queue {}, robots: {})", ARREF_VERSION,
               s.config.address, s.port.load(), s.config.workers, s.config.queue_size, s.robots->Ids());
  s.signals.async_wait([&s](const boost::system::error_code& ec, int signal) {
    if (!ec) s.BeginShutdown(signal == SIGTERM ? "SIGTERM" : "SIGINT");
    if (!ec)  // a second signal escalates (cancels running jobs)
      s.signals.async_wait([&s](const boost::system::error_code& ec2, int) {
        if (!ec2) s.BeginShutdown("signal");
      });
  });
  s.Accept();
  NotifySystemd(fmt::format("READY=1\nSTATUS=listening on {}:{}", s.config.address, s.port.load()));
  if (auto interval = WatchdogInterval()) {
    spdlog::info("systemd watchdog: notifying every {} ms", interval->count() / 1000);
    s.ArmWatchdog(*interval);
  }
  std::vector<std::thread> io_threads;
  for (int i = 1; i < s.config.io_threads; ++i) io_threads.emplace_back([&s] { s.ioc.run(); });
  s.ioc.run();
  for (auto& t : io_threads) t.join();
  s.jobs.Join();
  spdlog::info("arref-server stopped");
  return Status::Ok();
}

void Server::Stop() {
  net::post(impl_->strand, [impl = impl_.get()] { impl->BeginShutdown("Stop()"); });
}

std::uint16_t Server::port() const { return impl_->port; }

}  // namespace arref::server
