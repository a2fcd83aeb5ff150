#include "job_scheduler.h"

#include <spdlog/spdlog.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <new>

namespace arref::server {

void FinishCancelled(Job& job, const std::string& why) {
  JobOutcome outcome;
  outcome.status = Status::Cancelled(why);
  outcome.queue_ms = MsSince(job.accepted_at);
  if (job.on_done) job.on_done(job, outcome);
}

JobScheduler::JobScheduler(std::size_t workers, std::size_t queue_capacity, JobRunner runner)
    : runner_(std::move(runner)), capacity_(queue_capacity), workers_(std::max<std::size_t>(workers, 1)) {
  for (std::size_t i = 0; i < workers_; ++i) threads_.emplace_back([this, i] { WorkerLoop(static_cast<int>(i)); });
}

JobScheduler::~JobScheduler() {
  for (auto& job : CloseQueue()) FinishCancelled(*job, "server stopping");
  Join();
}

JobScheduler::SubmitResult JobScheduler::Submit(std::shared_ptr<Job> job, std::size_t* position, QueueInfo* info) {
  {
    std::lock_guard lock(mu_);
    if (closed_) return SubmitResult::kClosed;
    if (queued_ >= capacity_) return SubmitResult::kFull;
    const std::uint64_t session = job->session_id;
    auto& queue = queues_[session];
    if (queue.empty()) turns_.push_back(session);
    queue.push_back(std::move(job));
    ++queued_;
    const std::size_t ahead = PositionOf(session);
    if (position) *position = ahead;
    if (info) {
      info->position = ahead;
      // The job starts once all but workers-1 of the jobs ahead of it (queued and running) end.
      const std::size_t before = ahead + running_.size();
      double mean_run_ms = 0.0;
      for (double ms : recent_run_ms_) mean_run_ms += ms / static_cast<double>(recent_run_ms_.size());
      info->estimated_wait_ms =
          before < workers_ ? 0.0 : static_cast<double>(before - workers_ + 1) * mean_run_ms / static_cast<double>(workers_);
      if (auto it = waits_.find(session); it != waits_.end() && it->second.started > 0) {
        info->session_queue_ms = it->second.total_ms / static_cast<double>(it->second.started);
        info->session_jobs_started = it->second.started;
      }
    }
  }
  cv_.notify_one();
  return SubmitResult::kQueued;
}

// In round r (0-based) every session with more than r jobs queued runs one, in turn order.
// The session's last job runs in round i = its index; sessions before it in the turn order
// run min(n, i + 1) jobs before it, those after it min(n, i).
std::size_t JobScheduler::PositionOf(std::uint64_t session_id) const {
  const std::size_t index = queues_.at(session_id).size() - 1;
  std::size_t ahead = index;
  bool before = true;
  for (std::uint64_t s : turns_) {
    if (s == session_id) {
      before = false;
      continue;
    }
    ahead += std::min(queues_.at(s).size(), before ? index + 1 : index);
  }
  return ahead;
}

void JobScheduler::EraseQueued(std::uint64_t session_id, std::deque<std::shared_ptr<Job>>::iterator it) {
  auto& queue = queues_.at(session_id);
  queue.erase(it);
  --queued_;
  if (queue.empty()) {
    queues_.erase(session_id);
    turns_.erase(std::find(turns_.begin(), turns_.end(), session_id));
  }
}

JobScheduler::CancelResult JobScheduler::Cancel(std::uint64_t session_id, std::uint64_t request_id,
                                                std::shared_ptr<Job>* removed) {
  std::lock_guard lock(mu_);
  auto matches = [&](const std::shared_ptr<Job>& j) {
    return j->session_id == session_id && j->request_id == request_id;
  };
  if (auto q = queues_.find(session_id); q != queues_.end()) {
    if (auto it = std::find_if(q->second.begin(), q->second.end(), matches); it != q->second.end()) {
      *removed = *it;
      EraseQueued(session_id, it);
      return CancelResult::kRemovedFromQueue;
    }
  }
  if (auto it = std::find_if(running_.begin(), running_.end(), matches); it != running_.end() && !(*it)->finished) {
    (*it)->cancel.Cancel();
    return CancelResult::kFlaggedRunning;
  }
  return CancelResult::kNotFound;
}

std::vector<std::shared_ptr<Job>> JobScheduler::CancelSession(std::uint64_t session_id) {
  std::lock_guard lock(mu_);
  std::vector<std::shared_ptr<Job>> removed;
  if (auto q = queues_.find(session_id); q != queues_.end()) {
    removed.assign(q->second.begin(), q->second.end());
    queued_ -= removed.size();
    queues_.erase(q);
    turns_.erase(std::find(turns_.begin(), turns_.end(), session_id));
  }
  waits_.erase(session_id);
  for (auto& job : running_)
    if (job->session_id == session_id) job->cancel.Cancel();
  return removed;
}

std::vector<std::shared_ptr<Job>> JobScheduler::CloseQueue() {
  std::vector<std::shared_ptr<Job>> removed;
  {
    std::lock_guard lock(mu_);
    closed_ = true;
    for (auto& [session, queue] : queues_) removed.insert(removed.end(), queue.begin(), queue.end());
    queues_.clear();
    turns_.clear();
    queued_ = 0;
  }
  cv_.notify_all();
  return removed;
}

void JobScheduler::CancelAllRunning() {
  std::lock_guard lock(mu_);
  for (auto& job : running_) job->cancel.Cancel();
}

std::size_t JobScheduler::running() const {
  std::lock_guard lock(mu_);
  return running_.size();
}

void JobScheduler::NotifyWhenDrained(std::function<void()> drained) {
  {
    std::lock_guard lock(mu_);
    if (!closed_ || !running_.empty()) {
      drained_ = std::move(drained);
      return;
    }
  }
  if (drained) drained();
}

void JobScheduler::Join() {
  for (auto& t : threads_)
    if (t.joinable()) t.join();
  threads_.clear();
}

std::shared_ptr<Job> JobScheduler::Pop(double* waited_ms, SessionWaits* waits, bool* cores_shared) {
  std::unique_lock lock(mu_);
  cv_.wait(lock, [this] { return closed_ || queued_ > 0; });
  if (queued_ == 0) return nullptr;
  const std::uint64_t session = turns_.front();
  turns_.pop_front();
  auto& queue = queues_.at(session);
  auto job = queue.front();
  queue.pop_front();
  --queued_;
  if (queue.empty())
    queues_.erase(session);
  else
    turns_.push_back(session);  // its next job waits for every other session's turn
  running_.push_back(job);
  *cores_shared = running_.size() > 1 || queued_ > 0;
  *waited_ms = MsSince(job->accepted_at);
  SessionWaits& w = waits_[session];
  ++w.started;
  w.total_ms += *waited_ms;
  w.max_ms = std::max(w.max_ms, *waited_ms);
  *waits = w;
  return job;
}

void JobScheduler::RecordRunMs(double ms) {
  std::lock_guard lock(mu_);
  constexpr std::size_t kRecent = 16;
  recent_run_ms_.push_back(ms);
  if (recent_run_ms_.size() > kRecent) recent_run_ms_.pop_front();
}

void JobScheduler::WorkerLoop(int index) {
  double waited_ms = 0.0;
  SessionWaits waits;
  bool cores_shared = false;
  // With other jobs running or waiting, a job's parallel loops run on its own worker alone: the
  // cores are already busy with other sessions' jobs, and TBB's threads would only contend with
  // them (a 50-headset soak: about +10 % results/s, docs/architecture.md). A job alone on the
  // server has every core, so a single request's latency is unchanged.
  tbb::task_arena serial(1, 1);
  while (auto job = Pop(&waited_ms, &waits, &cores_shared)) {
    spdlog::info("worker {}: session {} request {} started after {:.0f} ms queued (session: {} started, queue wait "
                 "mean {:.0f} ms, max {:.0f} ms)", index, job->session_id, job->request_id, waited_ms, waits.started,
                 waits.total_ms / static_cast<double>(waits.started), waits.max_ms);
    const auto start = SteadyClock::now();
    JobOutcome outcome;
    try {
      if (cores_shared && workers_ > 1)
        serial.execute([&] { outcome = runner_(*job); });
      else
        outcome = runner_(*job);
    } catch (const std::bad_alloc&) {
      outcome.status = Status::ResourceExhausted(
                              "out of memory while registering (std::bad_alloc); the server keeps serving");
    } catch (const std::exception& e) {
      outcome.status = Status::Internal(std::string("registration threw: ") + e.what());
    }
    RecordRunMs(MsSince(start));
    outcome.queue_ms = std::max(outcome.queue_ms, 0.0);
    // Deliver before leaving running_: shutdown waits for running_ to empty and then closes
    // sessions, so the result must already be on its way.
    job->finished = true;  // a client may answer the result with a cancel before running_ is updated
    Deliver(*job, outcome);
    std::function<void()> drained;
    {
      std::lock_guard lock(mu_);
      running_.erase(std::find(running_.begin(), running_.end(), job));
      if (closed_ && running_.empty()) drained = std::exchange(drained_, nullptr);
    }
    if (drained) drained();
  }
}

// on_done builds and posts the result frame; if even that runs out of memory, a smaller
// answer is tried, and the worker goes on either way.
void JobScheduler::Deliver(Job& job, const JobOutcome& outcome) {
  if (!job.on_done) return;
  try {
    job.on_done(job, outcome);
    return;
  } catch (const std::exception& e) {
    spdlog::error("session {} request {}: delivering the result threw: {}", job.session_id, job.request_id, e.what());
  }
  try {
    JobOutcome failed;
    failed.status = Status::ResourceExhausted( "the result could not be built (out of memory)");
    failed.queue_ms = outcome.queue_ms;
    job.on_done(job, failed);
  } catch (const std::exception& e) {
    spdlog::error("session {} request {}: its result is lost: {}", job.session_id, job.request_id, e.what());
  }
}

}  // namespace arref::server
