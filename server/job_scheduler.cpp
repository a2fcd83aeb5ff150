#include "job_scheduler.h"

#include <spdlog/spdlog.h>

#include <algorithm>

namespace arref::server {

void FinishCancelled(Job& job, const std::string& why) {
  JobOutcome outcome;
  outcome.status = Status::Cancelled(why);
  outcome.queue_ms = MsSince(job.accepted_at);
  if (job.on_done) job.on_done(job, outcome);
}

JobScheduler::JobScheduler(std::size_t workers, std::size_t queue_capacity, JobRunner runner)
    : runner_(std::move(runner)), capacity_(queue_capacity) {
  for (std::size_t i = 0; i < std::max<std::size_t>(workers, 1); ++i)
    threads_.emplace_back([this, i] { WorkerLoop(static_cast<int>(i)); });
}

JobScheduler::~JobScheduler() {
  for (auto& job : CloseQueue()) FinishCancelled(*job, "server stopping");
  Join();
}

JobScheduler::SubmitResult JobScheduler::Submit(std::shared_ptr<Job> job, std::size_t* position) {
  {
    std::lock_guard lock(mu_);
    if (closed_) return SubmitResult::kClosed;
    if (queue_.size() >= capacity_) return SubmitResult::kFull;
    if (position) *position = queue_.size();
    queue_.push_back(std::move(job));
  }
  cv_.notify_one();
  return SubmitResult::kQueued;
}

JobScheduler::CancelResult JobScheduler::Cancel(std::uint64_t session_id, std::uint64_t request_id,
                                                std::shared_ptr<Job>* removed) {
  std::lock_guard lock(mu_);
  auto matches = [&](const std::shared_ptr<Job>& j) {
    return j->session_id == session_id && j->request_id == request_id;
  };
  if (auto it = std::find_if(queue_.begin(), queue_.end(), matches); it != queue_.end()) {
    *removed = *it;
    queue_.erase(it);
    return CancelResult::kRemovedFromQueue;
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
  for (auto it = queue_.begin(); it != queue_.end();) {
    if ((*it)->session_id == session_id) {
      removed.push_back(*it);
      it = queue_.erase(it);
    } else {
      ++it;
    }
  }
  for (auto& job : running_)
    if (job->session_id == session_id) job->cancel.Cancel();
  return removed;
}

std::vector<std::shared_ptr<Job>> JobScheduler::CloseQueue() {
  std::vector<std::shared_ptr<Job>> removed;
  {
    std::lock_guard lock(mu_);
    closed_ = true;
    removed.assign(queue_.begin(), queue_.end());
    queue_.clear();
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

std::shared_ptr<Job> JobScheduler::Pop() {
  std::unique_lock lock(mu_);
  cv_.wait(lock, [this] { return closed_ || !queue_.empty(); });
  if (queue_.empty()) return nullptr;
  auto job = queue_.front();
  queue_.pop_front();
  running_.push_back(job);
  return job;
}

void JobScheduler::WorkerLoop(int index) {
  while (auto job = Pop()) {
    spdlog::debug("worker {}: session {} request {} started", index, job->session_id, job->request_id);
    JobOutcome outcome;
    try {
      outcome = runner_(*job);
    } catch (const std::exception& e) {
      outcome.status = Status::Internal(std::string("registration threw: ") + e.what());
    }
    outcome.queue_ms = std::max(outcome.queue_ms, 0.0);
    // Deliver before leaving running_: shutdown waits for running_ to empty and then closes
    // sessions, so the result must already be on its way.
    job->finished = true;  // a client may answer the result with a cancel before running_ is updated
    if (job->on_done) job->on_done(*job, outcome);
    std::function<void()> drained;
    {
      std::lock_guard lock(mu_);
      running_.erase(std::find(running_.begin(), running_.end(), job));
      if (closed_ && running_.empty()) drained = std::exchange(drained_, nullptr);
    }
    if (drained) drained();
  }
}

}  // namespace arref::server
