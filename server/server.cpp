#include "server.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <csignal>
#include <iostream>
#include <map>
#include <set>
#include <mutex>
#include <thread>

#include "arref/base/clock.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/robot/joint_motion.h"
#include "mapping_motion.h"
#include "registration_job.h"
#include "robot_registry.h"
#include "session.h"
#include "systemd_notify.h"

namespace arref::server {
namespace {

constexpr auto kCancelGrace = std::chrono::seconds(10);   // after cancelling overdue jobs
constexpr auto kFlushGrace = std::chrono::seconds(5);     // for sessions to send their last bytes

Status CancelledWhileRunning() { return Status::Cancelled("cancelled while running"); }

// When the joints moved while the map was made, the links the fit rests on (ChooseMovingFit,
// against the map's resolution) and what the Result says about it. Null: every link. When much
// of the robot moved, the map does not show it as posed: the job's status is capped.
Result<std::optional<std::set<std::string>>> MovingFitLinks(Job& job, const ServedRobot& robot, JobOutcome* out) {
  const JointRanges& ranges = job.joints_while_mapping;  // the robot's own joints (MappingMotion::For)
  if (LargestRange(ranges) <= kJointMotionWhileMappingRad) return std::optional<std::set<std::string>>();
  const double voxel = MedianEdgeLength(*job.scene_world);
  ARREF_ASSIGN_OR_RETURN(const MovingFit fit, ChooseMovingFit(robot.model, job.joints, ranges,
                                                              kJointMotionWhileMappingRad, voxel, kMovingFitMinLeverageVoxels,
                                                              kMovingFitMinMovedShare));
  const std::string names = fmt::format("{}", fmt::join(fit.unmoved, ", "));
  if (fit.much_moved)
    job.options.map_not_as_posed = fmt::format(
        "the links that moved while the map was made are {:.0f} % of the robot: the map does not show it as posed",
        100 * (1.0 - fit.unmoved_area_share));
  std::optional<std::set<std::string>> links;
  if (job.seedless) {  // a base alone would be searched for all over the room: not measured, not done
    out->moving_fit_note = "a search of the whole map looks for the whole model, smeared mesh and all";
  } else if (fit.links) {
    links = fit.links;
    out->fitted_links.assign(fit.links->begin(), fit.links->end());
    out->moving_fit_note = fmt::format("the fit rests on the links that did not move ({})", names);
  } else if (fit.unmoved.empty()) {
    out->moving_fit_note = "every link moved: the fit rests on the whole model, smeared mesh and all";
  } else if (!fit.much_moved) {
    out->moving_fit_note = fmt::format("the moving links hold only {:.0f} % of the robot's surface: the fit rests on "
                                       "the whole model", 100 * (1.0 - fit.unmoved_area_share));
  } else {
    out->moving_fit_note = fmt::format(
        "the links that did not move ({}) cannot fix the heading on a mesh of {:.0f} mm edges (their moment arm about the "
        "base's axis is {:.0f} mm): the fit rests on the whole model, smeared mesh and all",
        names, voxel * 1000, fit.yaw_leverage_m * 1000);
  }
  spdlog::info("session {}: request {}: the joints moved while mapping; {}", job.session_id, job.request_id,
               out->moving_fit_note);
  return links;
}

}  // namespace

JobOutcome RunRegistrationJob(Job& job, RobotRegistry& robots) {
  JobOutcome out;
  out.queue_ms = MsSince(job.accepted_at);
  const auto start = SteadyClock::now();
  const auto finish = [&](Status status) -> JobOutcome {
    out.status = std::move(status);
    out.run_ms = MsSince(start);
    return std::move(out);
  };
  if (Cancelled(&job.cancel)) return finish(CancelledWhileRunning());
  if (job.on_progress) job.on_progress("model", 0.0);
  const ServedRobot* robot = robots.Find(job.robot_id);
  auto links = MovingFitLinks(job, *robot, &out);
  if (!links.ok()) return finish(links.status().WithContext("the links that did not move while mapping"));
  auto model = robots.Model(*robot, job.joints, job.options.model_samples, job.options.sample_seed,
                            *links ? &**links : nullptr);
  if (!model.ok()) return finish(model.status().WithContext("robot model"));
  if (Cancelled(&job.cancel)) return finish(CancelledWhileRunning());
  const ProgressFn progress = [&job](std::string_view stage, double fraction) {
    // A cancelled job reports no further progress: its next message is the CANCELLED result.
    if (job.on_progress && !Cancelled(&job.cancel)) job.on_progress(stage, 0.05 + 0.95 * fraction);
  };
  if (job.seedless) {
    auto whole = RegisterWholeMap(**model, *job.scene_world, job.options, job.hint, progress, &job.cancel);
    if (whole.status().code() == StatusCode::kCancelled || Cancelled(&job.cancel)) return finish(CancelledWhileRunning());
    if (!whole.ok()) return finish(whole.status());
    out.seedless = true;
    out.primary = whole->primary;
    out.instances = std::move(whole->instances);
    if (out.primary < 0) return finish(Status::NotFound("the robot was not found in the map: " + whole->status_reason));
    out.report = out.instances[static_cast<std::size_t>(out.primary)].report;
    out.report->stages_run.insert(out.report->stages_run.begin(), whole->stages_run.begin(), whole->stages_run.end());
    out.report->timings.insert(out.report->timings.begin(), whole->timings.begin(), whole->timings.end());
    return finish(Status::Ok());
  }
  auto report = RegisterScene(**model, *job.scene_world, job.T_world_seed, job.options, progress, &job.cancel);
  // A cancel that arrives after the pipeline's last check still wins, as it did when every
  // stage boundary (the final "done" included) was a cancellation point.
  if (report.status().code() == StatusCode::kCancelled || Cancelled(&job.cancel))
    return finish(CancelledWhileRunning());
  if (!report.ok()) return finish(report.status());
  out.report = std::move(*report);
  return finish(Status::Ok());
}

struct Server::Impl {
  Impl(ServerConfig c, std::unique_ptr<RobotRegistry> r, std::unique_ptr<TlsContext> t)
      : config(std::move(c)),
        robots(std::move(r)),
        tls(std::move(t)),
        memory(config.limits.memory_budget_bytes),
        jobs(static_cast<std::size_t>(config.workers), config.queue_size,
             [this](Job& job) { return RunRegistrationJob(job, *robots); }),
        ctx{config,
            *robots,
            jobs,
            hub,
            tracking,
            shutting_down,
            memory,
            [this](std::uint64_t id) { return AdmitSession(id); },
            [this](std::uint64_t id) { OnSessionClosed(id); },
            ARREF_VERSION,
            tls.get()},
        strand(net::make_strand(ioc)),
        acceptor(strand),
        signals(strand, SIGINT, SIGTERM),
        watchdog_timer(strand),
        jobs_timer(strand),
        sessions_timer(strand) {}

  ~Impl() {
    for (auto& job : jobs.CloseQueue()) FinishCancelled(*job, "server stopping");
    jobs.CancelAllRunning();
    jobs.Join();
    tracking.Shutdown();  // its workers send to sessions: stopped before their I/O goes
  }

  Status Listen();
  void Accept();
  void OnAccept(const boost::system::error_code& ec, tcp::socket socket);
  // Registers a new connection (pending until Hello); an error refuses it.
  Status AddConnection(const std::shared_ptr<Session>& session, const std::string& address,
                       std::shared_ptr<Session>* evicted);
  Status AdmitSession(std::uint64_t id);
  void OnSessionClosed(std::uint64_t id);
  std::vector<std::shared_ptr<Session>> SessionsSnapshot();
  void ArmWatchdog(std::chrono::microseconds interval);
  void BeginShutdown(const std::string& why);
  // Each phase waits on a timer for its grace period; the event it waits for (the last job
  // ended, the last session closed) cancels that timer, so it proceeds at once.
  void WaitForRunningJobs(std::chrono::milliseconds grace, bool cancelled);
  void OnJobsDrained();
  void CloseSessions();
  void OnSessionsClosed();
  void StopServing();
  void RunIo();

  ServerConfig config;
  std::unique_ptr<RobotRegistry> robots;
  std::unique_ptr<TlsContext> tls;  // nullptr: plain TCP
  SubscriberHub hub;
  TrackingService tracking{hub};
  std::atomic<bool> shutting_down{false};
  MemoryBudget memory;  // outlives everything that holds a reservation (jobs, sessions)
  JobScheduler jobs;
  ServerContext ctx;
  // Declared after everything sessions refer to, so handlers die first.
  net::io_context ioc;
  net::strand<net::io_context::executor_type> strand;  // acceptor, signals, timers
  tcp::acceptor acceptor;
  net::signal_set signals;
  net::steady_timer watchdog_timer;
  net::steady_timer jobs_timer;      // grace for running jobs
  net::steady_timer sessions_timer;  // grace for sessions to flush and close
  bool jobs_drained = false;         // on the strand, like the shutdown phases
  bool closing_sessions = false;
  bool stopped = false;
  std::atomic<std::uint16_t> port{0};
  // Every open connection; `pending` (ordered by id, so oldest first) those still owing Hello.
  // Idle sockets are counted apart from sessions so that they cannot crowd out headsets.
  struct Connection {
    std::shared_ptr<Session> session;
    std::string address;
    bool admitted = false;  // past Hello
  };
  std::mutex sessions_mu;
  std::map<std::uint64_t, Connection> sessions;
  std::set<std::uint64_t> pending;
  std::size_t admitted = 0;  // connections past Hello
  std::map<std::string, std::size_t> per_peer;
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
  const auto endpoint = socket.remote_endpoint(ignored);
  const std::string address = ignored ? "?" : endpoint.address().to_string();
  std::shared_ptr<Session> session;
  std::shared_ptr<Session> evicted;
  Status added;
  {
    std::lock_guard lock(sessions_mu);
    session = std::make_shared<Session>(std::move(socket), ctx, next_session_id++);
    added = AddConnection(session, address, &evicted);
  }
  if (evicted)
    evicted->Reject(wire::pb::ERROR_CODE_HANDSHAKE_TIMEOUT,
                    fmt::format("closed before Hello: {} connections are waiting for Hello (limits.max_pending_connections) "
                                "and this was the oldest", config.limits.max_pending_connections));
  if (!added.ok())
    session->Reject(wire::pb::ERROR_CODE_LIMIT_EXCEEDED, added.message());
  else
    session->Start();
  Accept();
}

// Under sessions_mu. A full pending set drops its oldest member rather than refusing the new
// connection: a headset that says Hello at once always gets in, however many idle sockets
// there are, as long as they come from fewer than all addresses' caps.
Status Server::Impl::AddConnection(const std::shared_ptr<Session>& session, const std::string& address,
                                   std::shared_ptr<Session>* evicted) {
  const ServerLimits& l = config.limits;
  if (per_peer[address] >= l.max_connections_per_peer)
    return Status::ResourceExhausted(fmt::format("too many connections from {}: {} open, limit {} "
                                                 "(limits.max_connections_per_peer)", address, per_peer[address],
                                                 l.max_connections_per_peer));
  if (pending.size() >= l.max_pending_connections) {
    const std::uint64_t oldest = *pending.begin();
    pending.erase(pending.begin());
    *evicted = sessions.at(oldest).session;
  }
  ++per_peer[address];
  sessions[session->id()] = Connection{.session = session, .address = address, .admitted = false};
  pending.insert(session->id());
  return Status::Ok();
}

Status Server::Impl::AdmitSession(std::uint64_t id) {
  std::lock_guard lock(sessions_mu);
  const auto it = sessions.find(id);
  if (it == sessions.end() || !pending.count(id))
    return Status::ResourceExhausted("this connection was dropped while it waited for Hello");
  if (admitted >= config.limits.max_sessions)
    return Status::ResourceExhausted(fmt::format("too many sessions: {} connected, limit {} (limits.max_sessions)",
                                                 admitted, config.limits.max_sessions));
  pending.erase(id);
  it->second.admitted = true;
  ++admitted;
  return Status::Ok();
}

void Server::Impl::OnSessionClosed(std::uint64_t id) {
  bool none_left = false;
  {
    std::lock_guard lock(sessions_mu);
    if (const auto it = sessions.find(id); it != sessions.end()) {
      pending.erase(id);
      if (it->second.admitted) --admitted;
      if (--per_peer[it->second.address] == 0) per_peer.erase(it->second.address);
      sessions.erase(it);
    }
    none_left = sessions.empty();
  }
  if (none_left && shutting_down) net::post(strand, [this] { OnSessionsClosed(); });
}

std::vector<std::shared_ptr<Session>> Server::Impl::SessionsSnapshot() {
  std::lock_guard lock(sessions_mu);
  std::vector<std::shared_ptr<Session>> out;
  for (auto& [id, c] : sessions) out.push_back(c.session);
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
  jobs.NotifyWhenDrained([this] { net::post(strand, [this] { OnJobsDrained(); }); });
  WaitForRunningJobs(std::chrono::milliseconds(static_cast<long long>(config.shutdown_grace_s * 1000)), false);
}

void Server::Impl::WaitForRunningJobs(std::chrono::milliseconds grace, bool cancelled) {
  if (jobs_drained) return;
  jobs_timer.expires_after(grace);
  jobs_timer.async_wait([this, cancelled](const boost::system::error_code& ec) {
    if (ec || jobs_drained) return;  // cancelled by OnJobsDrained, which went on already
    if (!cancelled) {
      spdlog::warn("{} jobs still running after the grace period: cancelling them", jobs.running());
      jobs.CancelAllRunning();
      WaitForRunningJobs(std::chrono::duration_cast<std::chrono::milliseconds>(kCancelGrace), true);
      return;
    }
    spdlog::error("{} jobs did not stop; their sessions close without a result", jobs.running());
    CloseSessions();
  });
}

void Server::Impl::OnJobsDrained() {
  if (jobs_drained) return;
  jobs_drained = true;
  jobs_timer.cancel();
  CloseSessions();
}

void Server::Impl::CloseSessions() {
  if (closing_sessions) return;
  closing_sessions = true;
  // Every result has been posted to its session before its job left `running`, so a close
  // posted now is queued behind it.
  const auto open = SessionsSnapshot();
  if (open.empty()) return StopServing();
  for (const auto& s : open) s->CloseGracefully("server shutting down");
  sessions_timer.expires_after(kFlushGrace);
  sessions_timer.async_wait([this](const boost::system::error_code& ec) {
    if (ec || stopped) return;
    std::size_t left = 0;
    {
      std::lock_guard lock(sessions_mu);
      left = sessions.size();
    }
    spdlog::warn("{} sessions did not close in time", left);
    StopServing();
  });
}

void Server::Impl::OnSessionsClosed() {
  if (!closing_sessions || stopped) return;  // sessions may all leave before the jobs end
  sessions_timer.cancel();
  StopServing();
}

void Server::Impl::StopServing() {
  if (stopped) return;
  stopped = true;
  signals.cancel();
  watchdog_timer.cancel();
  ioc.stop();
}

// Sessions catch what their handlers throw; this is the last line, so that one handler's
// exception (std::bad_alloc included) never ends the process for everyone.
void Server::Impl::RunIo() {
  while (true) {
    try {
      ioc.run();
      return;
    } catch (const std::exception& e) {
      spdlog::error("an I/O handler threw (serving goes on): {}", e.what());
    }
  }
}

// ---------------------------------------------------------------- Server

Server::Server(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Server::~Server() = default;

Result<std::unique_ptr<Server>> Server::Create(ServerConfig config) {
  ARREF_RETURN_IF_ERROR(ValidateServerConfig(config));
  std::unique_ptr<TlsContext> tls;
  if (config.tls.enabled()) {
    ARREF_ASSIGN_OR_RETURN(tls, TlsContext::Load(config.tls));
  }
  if (const std::string risk = ClearTextTokenRisk(config); !risk.empty())  // allowed, or validation refused it
    spdlog::warn("{} (server.allow_plaintext_token is set)", risk);
  ARREF_ASSIGN_OR_RETURN(auto robots, RobotRegistry::Load(config.robots, config.model_cache_entries));
  auto impl = std::make_unique<Impl>(std::move(config), std::move(robots), std::move(tls));
  return std::unique_ptr<Server>(new Server(std::move(impl)));
}

Status Server::Run() {
  Impl& s = *impl_;
  ARREF_RETURN_IF_ERROR(s.Listen());
  // The one machine-readable line on stdout (logs go to stderr): tests and scripts read the port.
  std::cout << "listening on " << s.config.address << ":" << s.port << std::endl;
  spdlog::info("arref-server {} listening on {}:{} ({} workers, queue {}, robots: {}; {})", ARREF_VERSION,
               s.config.address, s.port.load(), s.config.workers, s.config.queue_size, s.robots->Ids(),
               s.tls ? s.tls->description() : "plain TCP, no TLS");
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
  for (int i = 1; i < s.config.io_threads; ++i) io_threads.emplace_back([&s] { s.RunIo(); });
  s.RunIo();
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
