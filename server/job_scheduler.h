// Registration jobs: a bounded queue feeding a fixed pool of worker threads. No networking
// here; sessions hand in jobs with callbacks and get progress and the outcome back.
//
// Fair order: each session has its own FIFO queue and workers take jobs round-robin across
// the sessions that have any queued (one job per session per turn), so one session's full
// request window cannot sit ahead of everyone else's. A session's own jobs keep their order.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "arref/base/cancel.h"
#include "arref/base/clock.h"
#include "arref/base/frames.h"
#include "arref/base/geometry.h"
#include "arref/pipeline/pipeline.h"
#include "arref/pipeline/seedless.h"
#include "arref/robot/joint_motion.h"
#include "arref/robot/robot_model.h"
#include "arref/base/status.h"
#include "memory_budget.h"

namespace arref::server {

struct JobOutcome {
  std::optional<RegistrationReport> report;  // set when the pipeline produced a pose (seedless: the primary instance's)
  bool seedless = false;                     // the whole map was searched: instances below
  std::vector<FoundInstance> instances;
  int primary = -1;
  Status status;                             // why there is no report (kCancelled when cancelled)
  double queue_ms = 0.0;
  double run_ms = 0.0;
  // The joints moved while the map was made: what the fit rested on (ChooseMovingFit), for the
  // Result's message, and the links it rested on when not the whole model.
  std::string moving_fit_note;
  std::vector<std::string> fitted_links;
};

struct Job {
  std::uint64_t session_id = 0;
  std::uint64_t request_id = 0;
  std::string robot_id;
  JointValues joints;          // complete and validated
  // Each joint's range over the joint states the session sent while it mapped (ChooseMovingFit).
  JointRanges joints_while_mapping;
  std::shared_ptr<const TriangleMesh> scene_world;  // the session's map when the request came (shared, not copied)
  Iso3 T_world_seed = Iso3::Identity();
  bool seedless = false;       // no seed: the whole map is searched (RegisterWholeMap)
  InstanceHint hint;           // picks the primary instance of a seedless search
  RegistrationOptions options;
  FrameConvention result_frame = FrameConvention::kUnity;
  SteadyClock::time_point accepted_at = SteadyClock::now();
  double scene_time_unix_s = 0.0;     // when scene_world was taken (Result.scene_time_unix_s)
  double scene_headset_time_s = 0.0;  // its newest surface's headset timestamp
  // The one way to stop a job: Cancel messages, a closed session and shutdown cancel it; the
  // runner passes it to the pipeline, which returns Status::Cancelled.
  CancelToken cancel;
  std::atomic<bool> finished{false};  // its outcome is being delivered: too late to cancel
  MemoryBudget::Reservation memory;   // its charge on the server's budget, until it is destroyed

  // Called from worker threads (or the thread that cancels a queued job). on_done is called
  // exactly once per accepted job.
  std::function<void(std::string_view stage, double fraction)> on_progress;
  std::function<void(const Job&, const JobOutcome&)> on_done;
};

// Runs a job to completion on a worker thread; must honour job.cancel.
using JobRunner = std::function<JobOutcome(Job& job)>;

// What a session is told when its job is queued (Accepted) and what the logs show.
struct QueueInfo {
  std::size_t position = 0;          // jobs that run before this one in round-robin order, as queued now
  double estimated_wait_ms = 0.0;    // from the jobs ahead, the running ones and recent run times
  double session_queue_ms = 0.0;     // mean queue wait of this session's earlier jobs (0: none yet)
  std::size_t session_jobs_started = 0;
};

class JobScheduler {
 public:
  JobScheduler(std::size_t workers, std::size_t queue_capacity, JobRunner runner);
  ~JobScheduler();
  JobScheduler(const JobScheduler&) = delete;
  JobScheduler& operator=(const JobScheduler&) = delete;

  enum class SubmitResult { kQueued, kFull, kClosed };
  // position: jobs that will start before this one (round-robin order as queued now; a
  // session that queues later can still take its turn ahead of this job's later rounds).
  SubmitResult Submit(std::shared_ptr<Job> job, std::size_t* position, QueueInfo* info = nullptr);

  enum class CancelResult { kRemovedFromQueue, kFlaggedRunning, kNotFound };
  // A job removed from the queue is answered by the caller via on_done (see CancelQueued).
  CancelResult Cancel(std::uint64_t session_id, std::uint64_t request_id, std::shared_ptr<Job>* removed);
  // The session is gone: drops its queued jobs (returned) and flags its running ones.
  std::vector<std::shared_ptr<Job>> CancelSession(std::uint64_t session_id);

  // Shutdown: no more submissions; returns the jobs still queued (never to run).
  std::vector<std::shared_ptr<Job>> CloseQueue();
  void CancelAllRunning();
  std::size_t running() const;
  // Calls `drained` once, from the thread that sees it (a worker, or the caller if it is
  // already so), as soon as the queue is closed and no job runs any more. Every result has
  // been handed to on_done by then. One callback at a time; a later call replaces it.
  void NotifyWhenDrained(std::function<void()> drained);
  // Waits for the workers to exit (after CloseQueue and the running jobs end).
  void Join();

 private:
  struct SessionWaits {
    std::size_t started = 0;
    double total_ms = 0.0;
    double max_ms = 0.0;
  };

  void WorkerLoop(int index);
  std::shared_ptr<Job> Pop(double* waited_ms, SessionWaits* waits, bool* cores_shared);
  std::size_t PositionOf(std::uint64_t session_id) const;  // of the session's last queued job
  void EraseQueued(std::uint64_t session_id, std::deque<std::shared_ptr<Job>>::iterator it);
  void RecordRunMs(double ms);
  static void Deliver(Job& job, const JobOutcome& outcome);

  JobRunner runner_;
  std::size_t capacity_;
  std::size_t workers_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::map<std::uint64_t, std::deque<std::shared_ptr<Job>>> queues_;  // by session, never empty
  std::deque<std::uint64_t> turns_;  // sessions with queued jobs, whose turn comes first at the front
  std::size_t queued_ = 0;
  std::map<std::uint64_t, SessionWaits> waits_;  // by session, until it is cancelled
  std::deque<double> recent_run_ms_;             // the last few run times, for wait estimates
  std::vector<std::shared_ptr<Job>> running_;
  bool closed_ = false;
  std::function<void()> drained_;
  std::vector<std::thread> threads_;
};

// Answers a job that will never run.
void FinishCancelled(Job& job, const std::string& why);

}  // namespace arref::server
