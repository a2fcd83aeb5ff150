// JobScheduler in-process: queue limit, FIFO order, cancellation (queued and running),
// workers, shutdown. Runners block on gates the test opens, so no assertion depends on timing.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "job_scheduler.h"

namespace arref::server {
namespace {

// A one-shot event: Wait blocks until Open.
class Gate {
 public:
  void Open() {
    {
      std::lock_guard lock(mu_);
      open_ = true;
    }
    cv_.notify_all();
  }
  void Wait() {
    std::unique_lock lock(mu_);
    cv_.wait(lock, [this] { return open_; });
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool open_ = false;
};

// Collects on_done calls; WaitFor blocks until n outcomes arrived.
class Outcomes {
 public:
  void Add(std::uint64_t request_id, const JobOutcome& outcome) {
    {
      std::lock_guard lock(mu_);
      ids_.push_back(request_id);
      codes_.push_back(outcome.status.code());
    }
    cv_.notify_all();
  }
  void WaitFor(std::size_t n) {
    std::unique_lock lock(mu_);
    cv_.wait(lock, [&] { return ids_.size() >= n; });
  }
  std::vector<std::uint64_t> ids() {
    std::lock_guard lock(mu_);
    return ids_;
  }
  std::vector<StatusCode> codes() {
    std::lock_guard lock(mu_);
    return codes_;
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  std::vector<std::uint64_t> ids_;
  std::vector<StatusCode> codes_;
};

// Runs jobs in order of arrival, records their ids and threads. Job 1 (the "blocker") waits
// for `release` after announcing `started`, so later jobs stay queued until the test says.
struct Harness {
  Gate started;
  Gate release;
  Outcomes outcomes;
  std::mutex mu;
  std::vector<std::uint64_t> run_order;
  std::vector<std::thread::id> run_threads;

  JobRunner Runner() {
    return [this](Job& job) {
      {
        std::lock_guard lock(mu);
        run_order.push_back(job.request_id);
        run_threads.push_back(std::this_thread::get_id());
      }
      if (job.request_id == 1) {
        started.Open();
        release.Wait();
      }
      JobOutcome out;
      if (Cancelled(&job.cancel)) out.status = Status::Cancelled("cancelled while running");
      return out;
    };
  }

  std::shared_ptr<Job> MakeJob(std::uint64_t request_id, std::uint64_t session_id = 7) {
    auto job = std::make_shared<Job>();
    job->session_id = session_id;
    job->request_id = request_id;
    job->on_done = [this](const Job& done, const JobOutcome& outcome) { outcomes.Add(done.request_id, outcome); };
    return job;
  }
};

TEST(JobScheduler, FullQueueRefusesWithoutRunning) {
  Harness h;
  JobScheduler jobs(1, 2, h.Runner());
  std::size_t position = 99;
  ASSERT_EQ(jobs.Submit(h.MakeJob(1), &position), JobScheduler::SubmitResult::kQueued);
  EXPECT_EQ(position, 0u);
  h.started.Wait();  // job 1 occupies the only worker; the queue is empty again
  EXPECT_EQ(jobs.running(), 1u);
  ASSERT_EQ(jobs.Submit(h.MakeJob(2), &position), JobScheduler::SubmitResult::kQueued);
  EXPECT_EQ(position, 0u);
  ASSERT_EQ(jobs.Submit(h.MakeJob(3), &position), JobScheduler::SubmitResult::kQueued);
  EXPECT_EQ(position, 1u);
  // The session answers kFull with ERROR_CODE_BUSY; the refused job is never run or answered.
  EXPECT_EQ(jobs.Submit(h.MakeJob(4), &position), JobScheduler::SubmitResult::kFull);
  h.release.Open();
  h.outcomes.WaitFor(3);
  jobs.CloseQueue();
  jobs.Join();
  EXPECT_EQ(h.outcomes.ids(), (std::vector<std::uint64_t>{1, 2, 3}));
}

TEST(JobScheduler, OneWorkerRunsJobsInArrivalOrder) {
  Harness h;
  JobScheduler jobs(1, 16, h.Runner());
  ASSERT_EQ(jobs.Submit(h.MakeJob(1), nullptr), JobScheduler::SubmitResult::kQueued);
  h.started.Wait();
  for (std::uint64_t id : {5, 3, 4, 2}) ASSERT_EQ(jobs.Submit(h.MakeJob(id), nullptr), JobScheduler::SubmitResult::kQueued);
  h.release.Open();
  h.outcomes.WaitFor(5);
  jobs.CloseQueue();
  jobs.Join();
  EXPECT_EQ(h.run_order, (std::vector<std::uint64_t>{1, 5, 3, 4, 2}));
  EXPECT_EQ(h.outcomes.ids(), (std::vector<std::uint64_t>{1, 5, 3, 4, 2}));
  for (StatusCode code : h.outcomes.codes()) EXPECT_EQ(code, StatusCode::kOk);
}

// Session 7 queues its whole window first, then 8 and 9 queue theirs: the worker takes one job
// per session per turn, so 8 and 9 do not wait behind all of 7's jobs.
TEST(JobScheduler, WorkersTakeJobsRoundRobinAcrossSessions) {
  Harness h;
  JobScheduler jobs(1, 16, h.Runner());
  ASSERT_EQ(jobs.Submit(h.MakeJob(1, 7), nullptr), JobScheduler::SubmitResult::kQueued);
  h.started.Wait();  // job 1 runs; everything below waits in the queue
  std::vector<std::size_t> positions;
  auto submit = [&](std::uint64_t id, std::uint64_t session) {
    std::size_t position = 99;
    ASSERT_EQ(jobs.Submit(h.MakeJob(id, session), &position), JobScheduler::SubmitResult::kQueued);
    positions.push_back(position);
  };
  for (std::uint64_t id : {10, 11, 12, 13}) submit(id, 7);
  for (std::uint64_t id : {20, 21}) submit(id, 8);
  submit(30, 9);
  h.release.Open();
  h.outcomes.WaitFor(8);
  jobs.CloseQueue();
  jobs.Join();
  EXPECT_EQ(h.run_order, (std::vector<std::uint64_t>{1, 10, 20, 30, 11, 21, 12, 13}));
  // Positions as queued: 7's four alone (0..3); 8's first goes after 7's first (1), its second
  // after 7's second (3); 9's one after the first round of 7 and 8 (2).
  EXPECT_EQ(positions, (std::vector<std::size_t>{0, 1, 2, 3, 1, 3, 2}));
}

TEST(JobScheduler, AcceptedInfoCarriesTheSessionsQueueWait) {
  Harness h;
  JobScheduler jobs(1, 16, h.Runner());
  ASSERT_EQ(jobs.Submit(h.MakeJob(1, 7), nullptr), JobScheduler::SubmitResult::kQueued);
  h.started.Wait();
  QueueInfo first;
  ASSERT_EQ(jobs.Submit(h.MakeJob(2, 7), nullptr, &first), JobScheduler::SubmitResult::kQueued);
  EXPECT_EQ(first.session_jobs_started, 1u) << "job 1 has started";
  EXPECT_GE(first.session_queue_ms, 0.0);
  EXPECT_EQ(first.position, 0u);
  QueueInfo other;
  ASSERT_EQ(jobs.Submit(h.MakeJob(3, 9), nullptr, &other), JobScheduler::SubmitResult::kQueued);
  EXPECT_EQ(other.session_jobs_started, 0u) << "session 9 has no history";
  EXPECT_EQ(other.session_queue_ms, 0.0);
  EXPECT_EQ(other.position, 1u);
  h.release.Open();
  h.outcomes.WaitFor(3);
  jobs.CloseQueue();
  jobs.Join();
}

TEST(JobScheduler, CancelRemovesAQueuedJobAndFlagsARunningOne) {
  Harness h;
  JobScheduler jobs(1, 8, h.Runner());
  auto blocker = h.MakeJob(1);
  ASSERT_EQ(jobs.Submit(blocker, nullptr), JobScheduler::SubmitResult::kQueued);
  h.started.Wait();
  auto queued = h.MakeJob(2);
  ASSERT_EQ(jobs.Submit(queued, nullptr), JobScheduler::SubmitResult::kQueued);
  ASSERT_EQ(jobs.Submit(h.MakeJob(3), nullptr), JobScheduler::SubmitResult::kQueued);

  std::shared_ptr<Job> removed;
  ASSERT_EQ(jobs.Cancel(7, 2, &removed), JobScheduler::CancelResult::kRemovedFromQueue);
  EXPECT_EQ(removed, queued);
  FinishCancelled(*removed, "cancelled by the client while queued");  // what the session does
  EXPECT_EQ(jobs.Cancel(7, 2, &removed), JobScheduler::CancelResult::kNotFound);
  EXPECT_EQ(jobs.Cancel(8, 1, &removed), JobScheduler::CancelResult::kNotFound) << "another session's job";

  ASSERT_EQ(jobs.Cancel(7, 1, &removed), JobScheduler::CancelResult::kFlaggedRunning);
  EXPECT_TRUE(Cancelled(&blocker->cancel));
  h.release.Open();
  h.outcomes.WaitFor(3);
  jobs.CloseQueue();
  jobs.Join();
  EXPECT_EQ(h.run_order, (std::vector<std::uint64_t>{1, 3})) << "the cancelled queued job never runs";
  EXPECT_EQ(h.outcomes.ids(), (std::vector<std::uint64_t>{2, 1, 3}));
  EXPECT_EQ(h.outcomes.codes(), (std::vector<StatusCode>{StatusCode::kCancelled, StatusCode::kCancelled, StatusCode::kOk}));
}

TEST(JobScheduler, CancelSessionDropsItsQueuedJobsOnly) {
  Harness h;
  JobScheduler jobs(1, 8, h.Runner());
  auto blocker = h.MakeJob(1, 7);
  ASSERT_EQ(jobs.Submit(blocker, nullptr), JobScheduler::SubmitResult::kQueued);
  h.started.Wait();
  ASSERT_EQ(jobs.Submit(h.MakeJob(2, 7), nullptr), JobScheduler::SubmitResult::kQueued);
  ASSERT_EQ(jobs.Submit(h.MakeJob(3, 9), nullptr), JobScheduler::SubmitResult::kQueued);
  const auto dropped = jobs.CancelSession(7);
  ASSERT_EQ(dropped.size(), 1u);
  EXPECT_EQ(dropped[0]->request_id, 2u);
  EXPECT_TRUE(Cancelled(&blocker->cancel)) << "its running job is cancelled too";
  h.release.Open();
  h.outcomes.WaitFor(2);
  jobs.CloseQueue();
  jobs.Join();
  EXPECT_EQ(h.run_order, (std::vector<std::uint64_t>{1, 3}));
}

// A job alone on the server runs its parallel loops on every core; a job that starts beside
// another runs them on its own worker only (the cores are already busy: soak throughput +10 %).
TEST(JobScheduler, AJobAloneHasEveryCoreAndJobsSideBySideRunSerially) {
  Harness h;
  std::map<std::uint64_t, int> concurrency;
  JobRunner inner = h.Runner();
  JobScheduler jobs(2, 64, [&](Job& job) {
    {
      std::lock_guard lock(h.mu);
      concurrency[job.request_id] = tbb::this_task_arena::max_concurrency();
    }
    return inner(job);
  });
  ASSERT_EQ(jobs.Submit(h.MakeJob(1, 7), nullptr), JobScheduler::SubmitResult::kQueued);
  h.started.Wait();  // job 1 runs alone
  ASSERT_EQ(jobs.Submit(h.MakeJob(2, 8), nullptr), JobScheduler::SubmitResult::kQueued);
  h.outcomes.WaitFor(1);  // job 2 ran beside job 1 (which still waits for release)
  h.release.Open();
  h.outcomes.WaitFor(2);
  jobs.CloseQueue();
  jobs.Join();
  std::lock_guard lock(h.mu);
  EXPECT_EQ(concurrency.at(1), tbb::this_task_arena::max_concurrency());
  EXPECT_EQ(concurrency.at(2), 1);
}

TEST(JobScheduler, WorkersRunJobsOnTheirOwnThreads) {
  Outcomes outcomes;
  std::mutex mu;
  std::vector<std::thread::id> threads;
  JobScheduler jobs(3, 64, [&](Job&) {
    std::lock_guard lock(mu);
    threads.push_back(std::this_thread::get_id());
    return JobOutcome{};
  });
  constexpr std::uint64_t kJobs = 40;
  for (std::uint64_t id = 1; id <= kJobs; ++id) {
    auto job = std::make_shared<Job>();
    job->request_id = id;
    job->on_done = [&](const Job& done, const JobOutcome& outcome) { outcomes.Add(done.request_id, outcome); };
    ASSERT_EQ(jobs.Submit(job, nullptr), JobScheduler::SubmitResult::kQueued);
  }
  outcomes.WaitFor(kJobs);
  jobs.CloseQueue();
  jobs.Join();
  EXPECT_EQ(outcomes.ids().size(), kJobs) << "each job answered exactly once";
  ASSERT_EQ(threads.size(), kJobs);
  for (const auto& t : threads) EXPECT_NE(t, std::this_thread::get_id());
}

TEST(JobScheduler, ShutdownReturnsQueuedJobsAndNotifiesWhenDrained) {
  Harness h;
  JobScheduler jobs(1, 8, h.Runner());
  auto blocker = h.MakeJob(1);
  ASSERT_EQ(jobs.Submit(blocker, nullptr), JobScheduler::SubmitResult::kQueued);
  h.started.Wait();
  for (std::uint64_t id : {2, 3, 4}) ASSERT_EQ(jobs.Submit(h.MakeJob(id), nullptr), JobScheduler::SubmitResult::kQueued);

  const auto queued = jobs.CloseQueue();
  ASSERT_EQ(queued.size(), 3u);
  EXPECT_EQ(queued[0]->request_id, 2u);
  EXPECT_EQ(queued[2]->request_id, 4u);
  for (const auto& job : queued) FinishCancelled(*job, "server shutting down before the job started");
  EXPECT_EQ(jobs.Submit(h.MakeJob(5), nullptr), JobScheduler::SubmitResult::kClosed);

  Gate drained;
  std::atomic<bool> fired{false};
  jobs.NotifyWhenDrained([&] {
    fired = true;
    drained.Open();
  });
  // Job 1 waits for the release only this test gives, so the scheduler cannot be drained yet.
  EXPECT_FALSE(fired);
  jobs.CancelAllRunning();
  EXPECT_TRUE(Cancelled(&blocker->cancel));
  h.release.Open();
  drained.Wait();
  EXPECT_EQ(jobs.running(), 0u);
  jobs.Join();
  EXPECT_EQ(h.run_order, (std::vector<std::uint64_t>{1}));
  EXPECT_EQ(h.outcomes.codes(), (std::vector<StatusCode>{StatusCode::kCancelled, StatusCode::kCancelled,
                                                         StatusCode::kCancelled, StatusCode::kCancelled}));
  bool again = false;
  jobs.NotifyWhenDrained([&] { again = true; });
  EXPECT_TRUE(again) << "already drained: called at once";
}

}  // namespace
}  // namespace arref::server
