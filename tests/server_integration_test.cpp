// End-to-end tests of arref-server: the real server process on loopback, driven by the mock
// headset (its client library and, for the misbehaviour flags, its executable).
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "arref/fusion/model_reconstruction.h"
#include "arref/robot/joint_motion.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/metrics.h"
#include "arref/sim/room_simulator.h"
#include "frame_decoder.h"
#include "headset_client.h"
#include "server_process.h"
#include "track_client.h"
#include "test_support.h"

extern char** environ;

namespace arref::headset {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

const std::string kMockPath = ARREF_BINARY_DIR "/clients/mock_headset/arref-mock-headset";
constexpr double kReplyTimeout = 120.0;  // only to avoid hanging; never a speed assertion

// Success = ADD within this of the truth. PCL ICP from user-like seeds (~0.1 m, ~15 deg off)
// lands around 1 cm off on these cells (measured here: median ADD 9.5 mm, 49 of 50 within 20 mm,
// one seed in a wrong basin at 0.6 m), so the bound is 30 mm and the
// tests ask for a success rate, not every seed.
constexpr double kAddSuccessM = 0.030;
constexpr double kMinSuccessRate = 0.8;

using arref::testing::ServerProcess;
using arref::testing::ServerSettings;

// Simulated cells shared by all tests (simulating is the slow part of a client).
const HeadsetScene& Scene(std::uint64_t rng_seed) {
  static std::map<std::uint64_t, HeadsetScene> scenes;
  static std::mutex mu;
  std::lock_guard lock(mu);
  auto it = scenes.find(rng_seed);
  if (it == scenes.end()) {
    auto scene = SimulatedScene(rng_seed);
    EXPECT_TRUE(scene.ok()) << scene.status().ToString();
    it = scenes.emplace(rng_seed, scene.ok() ? std::move(*scene) : HeadsetScene{}).first;
  }
  return it->second;
}

HeadsetOptions Options(const ServerProcess& server) {
  HeadsetOptions o;
  o.host = "127.0.0.1";
  o.port = server.port();
  o.timeout_s = kReplyTimeout;
  o.batch_interval_s = 0.01;
  return o;
}

bool Succeeded(const RegistrationOutcome& r) {
  return r.result.status() == pb::RESULT_STATUS_OK && r.error && r.error->add_m <= kAddSuccessM;
}

// A well-behaved headset registers successfully (the server is still serving others).
void ExpectAnotherHeadsetSucceeds(const ServerProcess& server) {
  HeadsetOptions o = Options(server);
  o.client_name = "bystander";
  const HeadsetRun run = RunHeadset(Scene(1), o);
  ASSERT_TRUE(run.status.ok()) << run.status.ToString();
  ASSERT_EQ(run.registrations.size(), 1u);
  EXPECT_EQ(run.registrations[0].result.status(), pb::RESULT_STATUS_OK);
}

// Low-level session for tests that script the protocol by hand.
class ScriptedHeadset {
 public:
  explicit ScriptedHeadset(const ServerProcess& server) {
    auto conn = Connection::Connect("127.0.0.1", server.port(), 30);
    EXPECT_TRUE(conn.ok()) << conn.status().ToString();
    if (conn.ok()) conn_ = std::move(*conn);
  }
  void Send(const pb::ClientMessage& m) { ASSERT_TRUE(conn_.Send(m).ok()); }
  pb::ServerMessage Hello(std::uint32_t version = wire::kProtocolVersion) {
    pb::ClientMessage m;
    m.mutable_hello()->set_protocol_version(version);
    m.mutable_hello()->set_client_name("scripted");
    Send(m);
    return Next();
  }
  void Upload(const HeadsetScene& scene) {
    for (const auto& s : scene.surfaces) {
      pb::ClientMessage m;
      *m.mutable_surface_upsert() = wire::SurfaceToProto(s, FrameConvention::kUnity);
      Send(m);
    }
  }
  void Seed(const Iso3& T_world_seed) {
    pb::ClientMessage m;
    *m.mutable_seed_pose()->mutable_t_world_seed() = wire::PoseToProto(T_world_seed, FrameConvention::kUnity);
    m.mutable_seed_pose()->set_frame(pb::FRAME_CONVENTION_UNITY);
    Send(m);
  }
  void Request(std::uint64_t id, const std::string& robot = "kr5") {
    pb::ClientMessage m;
    m.mutable_register_request()->set_request_id(id);
    m.mutable_register_request()->set_robot_id(robot);
    Send(m);
  }
  // A request that takes seconds (the paper's ICP on the "big" sample count), so that it is
  // still running when a cancel arrives.
  void SlowRequest(std::uint64_t id) {
    pb::ClientMessage m;
    m.mutable_register_request()->set_request_id(id);
    m.mutable_register_request()->set_robot_id("kr5");
    m.mutable_register_request()->set_method("pcl-icp");
    m.mutable_register_request()->mutable_params()->set_scene_samples(256000);
    Send(m);
  }
  void Cancel(std::uint64_t id) {
    pb::ClientMessage m;
    m.mutable_cancel()->set_request_id(id);
    Send(m);
  }
  pb::ServerMessage Next() {
    auto m = conn_.Receive(kReplyTimeout);
    EXPECT_TRUE(m.ok()) << m.status().ToString();
    return m.ok() ? *m : pb::ServerMessage();
  }
  // Reads until a message satisfies pred (other messages are kept in seen()).
  template <typename Pred>
  pb::ServerMessage Await(Pred pred) {
    for (int i = 0; i < 100000; ++i) {
      auto m = conn_.Receive(kReplyTimeout);
      if (!m.ok()) {
        ADD_FAILURE() << "while waiting: " << m.status().ToString();
        return {};
      }
      seen_.push_back(*m);
      if (pred(*m)) return *m;
    }
    return {};
  }
  pb::ServerMessage AwaitResult(std::uint64_t id) {
    return Await([id](const pb::ServerMessage& m) { return m.has_result() && m.result().request_id() == id; });
  }
  pb::ServerMessage AwaitError() {
    return Await([](const pb::ServerMessage& m) { return m.has_error(); });
  }
  Result<pb::ServerMessage> Receive(double timeout_s) { return conn_.Receive(timeout_s); }
  const std::vector<pb::ServerMessage>& seen() const { return seen_; }
  void ShutdownWrite() { conn_.ShutdownWrite(); }
  void Close() { conn_.Close(); }

 private:
  Connection conn_;
  std::vector<pb::ServerMessage> seen_;
};

// ---------------------------------------------------------------- accuracy

// A test that dies without running destructors (a sanitizer's halt_on_error, a crash) must not
// leave its server running: ServerProcess has the server killed when the test process dies.
TEST(ServerIntegration, AServerDiesWithTheTestProcessThatStartedIt) {
  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  const pid_t test = fork();
  ASSERT_GE(test, 0);
  if (test == 0) {  // stands in for a test process that dies: no destructor runs
    close(fds[0]);
    ServerProcess server;
    const pid_t pid = server.pid();
    _exit(write(fds[1], &pid, sizeof pid) == sizeof pid ? 0 : 1);
  }
  close(fds[1]);
  pid_t server = -1;
  const bool read_pid = read(fds[0], &server, sizeof server) == sizeof server;
  close(fds[0]);
  int status = 0;
  waitpid(test, &status, 0);
  ServerProcess::RemoveFilesOf(test);  // what the stand-in's destructor would have removed
  ASSERT_TRUE(read_pid && server > 0) << "the stand-in test did not start its server";
  // Gone, or a zombie no one has reaped yet (in a container without an init that reaps).
  auto running = [&] {
    std::ifstream stat("/proc/" + std::to_string(server) + "/stat");
    std::string text((std::istreambuf_iterator<char>(stat)), std::istreambuf_iterator<char>());
    const std::size_t close_paren = text.rfind(')');
    return close_paren != std::string::npos && close_paren + 2 < text.size() && text[close_paren + 2] != 'Z';
  };
  const auto deadline = Clock::now() + std::chrono::seconds(10);
  while (running() && Clock::now() < deadline) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const bool orphaned = running();
  if (orphaned) kill(server, SIGKILL);
  EXPECT_FALSE(orphaned) << "arref-server " << server << " outlived the test process that started it";
}

TEST(ServerIntegration, RecoversTruePoseFromUserLikeSeeds) {
  ServerProcess server;
  int ok = 0, total = 0;
  std::vector<double> latencies;
  for (std::uint64_t cell : {1, 2, 3}) {
    for (int seed = 0; seed < 3; ++seed) {
      HeadsetOptions o = Options(server);
      o.seed_index = seed;
      const HeadsetRun run = RunHeadset(Scene(cell), o);
      ASSERT_TRUE(run.status.ok()) << "cell " << cell << " seed " << seed << ": " << run.status.ToString();
      const auto& r = run.registrations.at(0);
      ASSERT_TRUE(r.error.has_value());
      // The Unity pose and the internal matrix describe the same transform.
      auto M = wire::MatrixFromProto(r.result.t_world_base_internal());
      ASSERT_TRUE(M.ok());
      EXPECT_LT((M->matrix() - r.T_world_base.matrix()).cwiseAbs().maxCoeff(), 1e-6);
      ok += Succeeded(r);
      ++total;
      // The mock headset sends its wearer's path, as the app does; the result says it was used.
      const auto& stages = r.result.stages();
      EXPECT_NE(std::find(stages.begin(), stages.end(), "head-path"), stages.end());
      // So does the expected error: the map's part from that path's eyes, the fit's, the surface
      // model's (arref-icp fits two), their sum as variances, and the covariance they come from.
      const pb::Result& x = r.result;
      EXPECT_GT(x.map_error_m(), 0.0);
      EXPECT_GT(x.fit_error_m(), 0.0);
      EXPECT_GT(x.surface_error_m(), 0.0);
      EXPECT_NEAR(x.expected_error_m(), std::hypot(x.map_error_m(), x.fit_error_m(), x.surface_error_m()), 1e-9);
      EXPECT_LT(x.expected_error_m(), 0.015);
      ASSERT_EQ(x.covariance_size(), 16);
      EXPECT_NEAR(x.covariance(0) + x.covariance(5), x.sigma_horizontal_m() * x.sigma_horizontal_m(), 1e-12);
      EXPECT_NEAR(std::sqrt(x.covariance(15)) * 180 / std::numbers::pi, x.sigma_yaw_deg(), 1e-9);
      latencies.push_back(r.latency_ms);
      std::printf("cell %d seed %d: ADD %.1f mm, translation %.1f mm, rotation %.2f deg, %.0f ms\n",
                  static_cast<int>(cell), seed, r.error->add_m * 1e3, r.error->translation_m * 1e3,
                  r.error->rotation_deg, r.latency_ms);
    }
  }
  EXPECT_GE(ok, kMinSuccessRate * total) << ok << " of " << total << " within " << kAddSuccessM * 1e3 << " mm ADD";
}

// ---------------------------------------------------------------- seedless

// A simulated room with two arms of the built-in robot, as a headset maps it.
struct Room {
  sim::SimulatedRoom sim;
  HeadsetScene scene;
};

Room TwoArmRoom() {
  static const RobotModel robot = [] {
    auto r = RobotModel::Load(testing::BuiltinRobotUrdf());
    if (!r.ok()) throw std::runtime_error(r.status().ToString());
    return std::move(r).value();
  }();
  sim::RoomOptions options;
  options.arms = 2;
  options.max_side_m = 6.0;
  auto room = sim::SimulateRoom({&robot, nullptr}, options, 3);
  if (!room.ok()) throw std::runtime_error(room.status().ToString());
  Room out{std::move(*room), {}};
  out.scene.surfaces = out.sim.surfaces;
  return out;
}

void SetJoints(const JointValues& joints, pb::RegisterRequest* m) {
  for (const auto& [name, value] : joints) {
    m->mutable_joints()->add_names(name);
    m->mutable_joints()->add_positions(value);
  }
}

TEST(ServerIntegration, ARequestWithNoSeedFindsBothArmsOfARoom) {
  ServerProcess server;
  const Room room = TwoArmRoom();
  ScriptedHeadset h(server);
  ASSERT_TRUE(h.Hello().has_hello_reply());
  h.Upload(room.scene);
  pb::ClientMessage m;
  m.mutable_register_request()->set_request_id(5);
  m.mutable_register_request()->set_robot_id("kr5");
  SetJoints(room.sim.arms[0].joints, m.mutable_register_request());
  m.mutable_register_request()->set_result_frame(pb::FRAME_CONVENTION_ROS);
  h.Send(m);
  const pb::ServerMessage reply = h.AwaitResult(5);
  ASSERT_TRUE(reply.has_result());
  const pb::Result& r = reply.result();
  EXPECT_EQ(r.method(), "arref-icp");  // each instance is arref-icp's fit
  EXPECT_TRUE(std::any_of(h.seen().begin(), h.seen().end(), [](const pb::ServerMessage& s) {
    return s.has_progress() && s.progress().stage().find("candidate") != std::string::npos;
  }));
  ASSERT_GE(r.candidates_size(), 2) << r.message();
  ASSERT_GE(r.primary_candidate(), 0);
  // Every arm has a candidate on it (the robot's points under both poses within 2 cm on average).
  auto robot = RobotModel::Load(testing::BuiltinRobotUrdf());
  ASSERT_TRUE(robot.ok());
  auto posed = robot->PosedMesh(room.sim.arms[0].joints);
  ASSERT_TRUE(posed.ok());
  for (const sim::RoomArm& arm : room.sim.arms) {
    double best = 1e9;
    for (const pb::Candidate& c : r.candidates()) {
      auto T = wire::MatrixFromProto(c.t_world_base_internal());
      ASSERT_TRUE(T.ok());
      best = std::min(best, ComparePoses(*T, arm.T_world_base, posed->vertices).add_m);
    }
    EXPECT_LT(best, 0.02) << "arm at " << arm.T_world_base.translation().transpose();
  }
}

// The mock headset's --room: a whole simulated room mapped and referenced with no seed through the
// real server process, every instance printed with its error; a room without the arm is FAILED.
TEST(ServerIntegration, TheMockHeadsetReferencesARoomWithNoSeed) {
  ServerProcess server;
  const std::string base = kMockPath + " --port " + std::to_string(server.port()) + " --room --rng-seed 4 --timeout 120";
  const auto two = arref::testing::RunCommand(base + " --room-arms 2");
  ASSERT_EQ(two.exit_code, 0) << two.out << two.err;
  int near = 0;  // instances within 20 mm of an arm
  for (std::size_t at = two.out.find(" mm from the nearest arm"); at != std::string::npos;
       at = two.out.find(" mm from the nearest arm", at + 1)) {
    const std::size_t start = two.out.rfind(", ", at) + 2;
    near += std::stod(two.out.substr(start, at - start)) < 20.0;
  }
  EXPECT_GE(near, 2) << two.out;
  EXPECT_NE(two.out.find("* instance"), std::string::npos) << "the primary instance is marked\n" << two.out;
  EXPECT_NE(two.out.find("vs truth: ADD"), std::string::npos) << two.out;
  const auto none = arref::testing::RunCommand(base + " --room-arms 0");
  EXPECT_EQ(none.exit_code, 0) << none.out << none.err;
  EXPECT_NE(none.out.find("RESULT_STATUS_FAILED"), std::string::npos) << none.out;
  EXPECT_NE(none.out.find("FAILED with no instance, as it should"), std::string::npos) << none.out;
  ASSERT_TRUE(server.alive());
}

TEST(ServerIntegration, AMapOverTheLimitIsRefusedAndKeepsItsSurfaces) {
  ServerSettings settings;
  settings.max_map_triangles = 1000;
  ServerProcess server(settings);
  const Room room = TwoArmRoom();
  ScriptedHeadset h(server);
  const pb::ServerMessage hello = h.Hello();
  ASSERT_TRUE(hello.has_hello_reply());
  EXPECT_EQ(hello.hello_reply().limits().max_map_triangles(), 1000u);  // announced before it bites
  h.Upload(room.scene);
  h.Request(1);
  const pb::ServerMessage error = h.AwaitError();
  EXPECT_EQ(error.error().code(), pb::ERROR_CODE_LIMIT_EXCEEDED);
  EXPECT_NE(error.error().message().find("limits.max_map_triangles = 1000"), std::string::npos) << error.error().message();
  EXPECT_FALSE(error.error().fatal());
  // The surfaces are still there: a seeded request on them is answered.
  h.Seed(room.sim.arms[0].T_world_base * Iso3(Eigen::Translation3d(0.05, 0.05, 0.1)));
  pb::ClientMessage m;
  m.mutable_register_request()->set_request_id(2);
  m.mutable_register_request()->set_robot_id("kr5");
  SetJoints(room.sim.arms[0].joints, m.mutable_register_request());
  h.Send(m);
  const pb::ServerMessage reply = h.AwaitResult(2);
  ASSERT_TRUE(reply.has_result());
  EXPECT_EQ(reply.result().candidates_size(), 0);
  EXPECT_NE(reply.result().status(), pb::RESULT_STATUS_CANCELLED);
}

TEST(ServerIntegration, QuantizedVerticesAndRepeatedRequests) {
  ServerProcess server;
  HeadsetOptions o = Options(server);
  o.quantize_scale = 0.0005;  // 0.5 mm steps: int16 covers +-16 m
  o.repeat = 2;
  const HeadsetRun run = RunHeadset(Scene(1), o);
  ASSERT_TRUE(run.status.ok()) << run.status.ToString();
  ASSERT_EQ(run.registrations.size(), 2u);
  for (const auto& r : run.registrations) EXPECT_LE(r.error->add_m, 0.1);
}

// The soak's option of a new seed for each repeated request (scripts/soak.sh, SOAK_NEW_SEEDS): the
// session's seed moves, so the repeats are new registrations, not the first one again; each
// from a user-like seed still finds the robot.
TEST(ServerIntegration, RepeatsWithANewSeedEachAreNewRegistrations) {
  ServerProcess server;
  HeadsetOptions o = Options(server);
  o.repeat = 3;
  const HeadsetRun same = RunHeadset(Scene(1), o);
  o.new_seed_each_repeat = true;
  const HeadsetRun moved = RunHeadset(Scene(1), o);
  ASSERT_TRUE(same.status.ok() && moved.status.ok()) << same.status.ToString() << " / " << moved.status.ToString();
  ASSERT_EQ(same.registrations.size(), 3u);
  ASSERT_EQ(moved.registrations.size(), 3u);
  const auto pose = [](const RegistrationOutcome& r) { return r.T_world_base.matrix(); };
  EXPECT_EQ(pose(same.registrations[1]), pose(same.registrations[0]));
  EXPECT_EQ(pose(moved.registrations[0]), pose(same.registrations[0]));  // the first seed is the same
  EXPECT_NE(pose(moved.registrations[1]), pose(moved.registrations[0]));
  EXPECT_NE(pose(moved.registrations[2]), pose(moved.registrations[1]));
  for (const auto& r : moved.registrations) EXPECT_LE(r.error->add_m, 0.01) << "request " << r.request_id;
}

// ---------------------------------------------------------------- concurrency

TEST(ServerIntegration, TwentyConcurrentHeadsetsAllServed) {
  ServerProcess server({.workers = 2, .queue_size = 32});
  HeadsetOptions o = Options(server);
  const auto runs = RunHeadsets(Scene(1), o, 20);
  int ok = 0, total = 0;
  std::map<int, Iso3> by_seed;  // the same seed must give the same answer, whoever asked
  std::set<std::uint64_t> sessions;
  for (std::size_t i = 0; i < runs.size(); ++i) {
    ASSERT_TRUE(runs[i].status.ok()) << "headset " << i << ": " << runs[i].status.ToString();
    ASSERT_EQ(runs[i].registrations.size(), 1u);
    const auto& r = runs[i].registrations[0];
    EXPECT_EQ(r.result.session_id(), runs[i].session_id);
    sessions.insert(runs[i].session_id);
    const int seed = static_cast<int>(i % Scene(1).seeds.size());
    if (by_seed.count(seed))
      EXPECT_LT((by_seed[seed].matrix() - r.T_world_base.matrix()).cwiseAbs().maxCoeff(), 1e-6) << "headset " << i;
    else
      by_seed[seed] = r.T_world_base;
    ok += Succeeded(r);
    ++total;
  }
  EXPECT_EQ(sessions.size(), 20u);
  EXPECT_GE(ok, kMinSuccessRate * total) << ok << " of " << total;
  const LatencySummary s = SummarizeLatency(runs);
  const long rss = server.RssKb();
  std::printf("20 headsets: latency median %.0f ms, p95 %.0f ms; server VmRSS %ld kB\n", s.median_ms, s.p95_ms, rss);
  RecordProperty("latency_median_ms", static_cast<int>(s.median_ms));
  RecordProperty("latency_p95_ms", static_cast<int>(s.p95_ms));
  RecordProperty("server_rss_kb", static_cast<int>(rss));
}

TEST(ServerIntegration, BusyWhenTheQueueIsFull) {
  ServerProcess server({.workers = 1, .queue_size = 1});
  ScriptedHeadset h(server);
  ASSERT_TRUE(h.Hello().has_hello_reply());
  h.Upload(Scene(1));
  h.Seed(Scene(1).seeds[0]);
  for (std::uint64_t id = 1; id <= 4; ++id) h.Request(id);
  std::set<std::uint64_t> accepted, busy, answered;
  while (accepted.size() + busy.size() < 4 || answered.size() < accepted.size()) {
    const auto m = h.Next();
    if (m.has_accepted()) accepted.insert(m.accepted().request_id());
    if (m.has_error()) {
      EXPECT_EQ(m.error().code(), pb::ERROR_CODE_BUSY) << m.error().message();
      EXPECT_NE(m.error().message().find("queue"), std::string::npos);
      busy.insert(m.error().request_id());
    }
    if (m.has_result()) answered.insert(m.result().request_id());
    if (!m.has_accepted() && !m.has_error() && !m.has_result() && !m.has_progress()) break;
  }
  EXPECT_GE(busy.size(), 1u);
  EXPECT_GE(accepted.size(), 1u);
  EXPECT_EQ(answered, accepted);  // every accepted request got its result
}

// ---------------------------------------------------------------- cancellation

TEST(ServerIntegration, CancelQueuedAndRunningRequests) {
  ServerProcess server({.workers = 1, .queue_size = 8});
  ScriptedHeadset h(server);
  ASSERT_TRUE(h.Hello().has_hello_reply());
  h.Upload(Scene(1));
  h.Seed(Scene(1).seeds[0]);
  h.SlowRequest(1);
  h.Request(2);
  h.Await([](const pb::ServerMessage& m) { return m.has_accepted() && m.accepted().request_id() == 2; });
  // Request 2 waits behind request 1 (one worker): cancelling removes it from the queue.
  h.Cancel(2);
  const auto queued = h.AwaitResult(2);
  EXPECT_EQ(queued.result().status(), pb::RESULT_STATUS_CANCELLED);
  EXPECT_NE(queued.result().message().find("queued"), std::string::npos) << queued.result().message();
  // Request 1 is running once it reports progress; it stops at its next stage boundary.
  bool progressed = false;
  for (const auto& m : h.seen()) progressed |= m.has_progress() && m.progress().request_id() == 1;
  if (!progressed) h.Await([](const pb::ServerMessage& m) { return m.has_progress() && m.progress().request_id() == 1; });
  h.Cancel(1);
  const auto running = h.AwaitResult(1);
  EXPECT_EQ(running.result().status(), pb::RESULT_STATUS_CANCELLED) << running.result().message();
  EXPECT_NE(running.result().message().find("running"), std::string::npos) << running.result().message();
  // Cancelling something not in flight is a clear error; the session still works.
  h.Cancel(1);
  const auto unknown = h.AwaitError();
  EXPECT_EQ(unknown.error().code(), pb::ERROR_CODE_UNKNOWN_REQUEST);
  h.Request(3);
  EXPECT_EQ(h.AwaitResult(3).result().status(), pb::RESULT_STATUS_OK);
}

// ---------------------------------------------------------------- bad input

TEST(ServerIntegration, BadSurfaceIsRejectedAndTheOthersKept) {
  ServerProcess server;
  ScriptedHeadset h(server);
  ASSERT_TRUE(h.Hello().has_hello_reply());
  h.Upload(Scene(1));
  Surface bad = Scene(1).surfaces.front();
  bad.id = 9999;
  bad.mesh.vertices[0].x() = std::nanf("");
  pb::ClientMessage m;
  *m.mutable_surface_upsert() = wire::SurfaceToProto(bad, FrameConvention::kUnity);
  h.Send(m);
  auto e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_BAD_SURFACE);
  EXPECT_EQ(e.error().surface_id(), 9999u);
  EXPECT_NE(e.error().message().find("9999"), std::string::npos) << e.error().message();
  EXPECT_FALSE(e.error().fatal());
  // Out-of-range triangle index, and a missing frame convention.
  m.mutable_surface_upsert()->set_surface_id(9998);
  *m.mutable_surface_upsert() = wire::SurfaceToProto(Scene(1).surfaces.front(), FrameConvention::kUnity);
  m.mutable_surface_upsert()->set_surface_id(9998);
  m.mutable_surface_upsert()->set_triangles(0, 1u << 30);
  h.Send(m);
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_BAD_SURFACE);
  EXPECT_EQ(e.error().surface_id(), 9998u);
  m.mutable_surface_upsert()->set_triangles(0, 0);
  m.mutable_surface_upsert()->set_frame(pb::FRAME_CONVENTION_UNSPECIFIED);
  h.Send(m);
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_BAD_SURFACE);
  EXPECT_NE(e.error().message().find("frame"), std::string::npos) << e.error().message();
  // The good surfaces are all still there: registration works as before.
  h.Seed(Scene(1).seeds[0]);
  h.Request(1);
  const auto r = h.AwaitResult(1);
  ASSERT_EQ(r.result().status(), pb::RESULT_STATUS_OK) << r.result().message();
  EXPECT_GT(r.result().scene_triangles(), 1000u);
}

TEST(ServerIntegration, ClearErrorsForBadRequests) {
  ServerProcess server;
  {
    ScriptedHeadset h(server);  // not starting with Hello
    pb::ClientMessage ping;
    ping.mutable_ping()->set_nonce(1);
    h.Send(ping);
    const auto e = h.Next();
    EXPECT_EQ(e.error().code(), pb::ERROR_CODE_NOT_READY);
    EXPECT_TRUE(e.error().fatal());
  }
  ScriptedHeadset h(server);
  const auto hello = h.Hello();
  ASSERT_EQ(hello.hello_reply().robots_size(), 1);
  EXPECT_EQ(hello.hello_reply().robots(0).id(), "kr5");
  EXPECT_EQ(hello.hello_reply().robots(0).joint_names_size(), 6);
  {  // a method that needs a seed, with none: NO_SEED
    pb::ClientMessage seeded;
    seeded.mutable_register_request()->set_request_id(1);
    seeded.mutable_register_request()->set_robot_id("kr5");
    seeded.mutable_register_request()->set_method("pcl-icp");
    h.Send(seeded);
  }
  auto e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_NO_SEED);
  EXPECT_EQ(e.error().request_id(), 1u);
  h.Request(11);  // no seed and no method: a search of the whole map, which holds nothing yet
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_NO_SCENE);
  EXPECT_EQ(e.error().request_id(), 11u);
  h.Seed(Scene(1).seeds[0]);
  h.Request(2);
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_NO_SCENE);
  h.Upload(Scene(1));
  h.Request(3, "ur5");
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_UNKNOWN_ROBOT);
  EXPECT_NE(e.error().message().find("ur5"), std::string::npos);
  EXPECT_NE(e.error().message().find("kr5"), std::string::npos);
  pb::ClientMessage joints;
  joints.mutable_joint_state()->set_robot_id("kr5");
  joints.mutable_joint_state()->add_names("joint_nope");
  joints.mutable_joint_state()->add_positions(0.1);
  h.Send(joints);
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_NE(e.error().message().find("joint_nope"), std::string::npos) << e.error().message();
  // The rejected JointState is not silently replaced by defaults: the request fails naming it.
  h.Request(6);
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_EQ(e.error().request_id(), 6u);
  EXPECT_NE(e.error().message().find("JointState for robot 'kr5' was rejected"), std::string::npos) << e.error().message();
  EXPECT_NE(e.error().message().find("joint_nope"), std::string::npos) << e.error().message();
  joints.mutable_joint_state()->clear_names();
  joints.mutable_joint_state()->clear_positions();
  h.Send(joints);  // a valid (empty: every joint at its default) state replaces it
  pb::ClientMessage req;
  req.mutable_register_request()->set_request_id(4);
  req.mutable_register_request()->set_robot_id("kr5");
  req.mutable_register_request()->mutable_params()->set_crop_radius_m(-1);
  h.Send(req);
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_NE(e.error().message().find("crop_radius_m"), std::string::npos) << e.error().message();
  req.mutable_register_request()->clear_params();
  auto* path = req.mutable_register_request()->mutable_head_path();
  for (double x : {1.0, std::nan(""), 2.0}) {
    auto* p = path->add_positions();
    p->set_x(x), p->set_y(0), p->set_z(1.6);
  }
  h.Send(req);  // no frame
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_NE(e.error().message().find("head_path.frame"), std::string::npos) << e.error().message();
  path->set_frame(pb::FRAME_CONVENTION_UNITY);
  h.Send(req);
  e = h.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_NE(e.error().message().find("head_path.positions[1] is not finite"), std::string::npos) << e.error().message();
  h.Request(5);  // the session survived all of it
  const auto result = h.AwaitResult(5).result();
  EXPECT_EQ(result.status(), pb::RESULT_STATUS_OK);
  const auto& stages = result.stages();
  EXPECT_NE(std::find(stages.begin(), stages.end(), "in-context"), stages.end());
  EXPECT_EQ(std::find(stages.begin(), stages.end(), "head-path"), stages.end()) << "no path was sent";
}

TEST(ServerIntegration, VersionMismatchNamesBothVersions) {
  ServerProcess server;
  ScriptedHeadset h(server);
  const auto reply = h.Hello(7);
  ASSERT_TRUE(reply.has_error());
  EXPECT_EQ(reply.error().code(), pb::ERROR_CODE_VERSION_MISMATCH);
  EXPECT_TRUE(reply.error().fatal());
  EXPECT_NE(reply.error().message().find("version 7"), std::string::npos) << reply.error().message();
  EXPECT_NE(reply.error().message().find("version 1"), std::string::npos) << reply.error().message();
  auto closed = h.Receive(30);
  EXPECT_EQ(closed.status().code(), StatusCode::kUnavailable);
  ExpectAnotherHeadsetSucceeds(server);
}

// The mock headset reads `arref simulate`'s cell files and typed seeds with the command line's
// reader: each malformed part is named, and it stops before it connects (no server runs here).
TEST(MockHeadset, BadCellFilesGetClearErrors) {
  const arref::testing::ScopedTempDir tmp;
  const std::string dir = tmp.path();
  std::ofstream(dir + "/tri.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
  const std::string T = R"("T_world_base": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1])";
  struct Case {
    std::string json;
    std::string expected_output;
  };
  const std::vector<Case> cases{
      {"{not json", "is not valid JSON"},
      {"[1, 2]", "is not a JSON object"},
      {"{" + T + R"(, "frame": 3})", "frame must be a string"},
      {R"({"T_world_base": [1, 0, 0]})", "T_world_base: a 4x4 matrix must be 16 numbers"},
      {"{" + T + R"(, "seeds": [[0,0,0, 0,0,0,2]]})", "seeds[0]: pose quaternion is not unit length"},
      {"{" + T + R"(, "seeds": [[0,0,0, 0,0,0,1]], "joints": {"joint_a1": "up"}})", "joint 'joint_a1' is not a finite"},
      {"{" + T + R"(, "seeds": [[0,0,0, 0,0,0,1]], "head_path": [[0, 0]]})", "head_path: position 0 is not [x,y,z]"},
  };
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const std::string truth = dir + "/cell" + std::to_string(i) + ".json";
    std::ofstream(truth) << cases[i].json;
    const auto r = arref::testing::RunCommand(kMockPath + " --port 1 --scene " + dir + "/tri.obj --truth " + truth);
    EXPECT_EQ(r.exit_code, 3) << cases[i].json << "\n" << r.out << r.err;
    EXPECT_NE((r.out + r.err).find(cases[i].expected_output), std::string::npos) << cases[i].json << "\n" << r.out << r.err;
  }
  // A typed seed goes through the same pose check.
  const auto r = arref::testing::RunCommand(kMockPath + " --port 1 --scene " + dir + "/tri.obj --seed 0,0,0,0,0,0,2");
  EXPECT_EQ(r.exit_code, 3) << r.out << r.err;
  EXPECT_NE(r.err.find("--seed: pose quaternion is not unit length"), std::string::npos) << r.err;
  // The truth's errors are measured on --truth-robot: a cell of another robot says which to give,
  // and a robot that cannot be loaded is named.
  const std::string other = dir + "/other.json";
  std::ofstream(other) << "{" + T + R"(, "seeds": [[0,0,0, 0,0,0,1]], "joints": {"joint_s": 0.1}})";
  const auto wrong = arref::testing::RunCommand(kMockPath + " --port 1 --scene " + dir + "/tri.obj --truth " + other);
  EXPECT_EQ(wrong.exit_code, 3) << wrong.out << wrong.err;
  EXPECT_NE(wrong.err.find("unknown joint 'joint_s'"), std::string::npos) << wrong.err;
  EXPECT_NE(wrong.err.find("--truth-robot"), std::string::npos) << wrong.err;
  const auto missing = arref::testing::RunCommand(kMockPath + " --port 1 --scene " + dir + "/tri.obj --truth " + other +
                                                  " --truth-robot " + dir + "/none.urdf");
  EXPECT_EQ(missing.exit_code, 3) << missing.out << missing.err;
  EXPECT_NE(missing.err.find("--truth-robot"), std::string::npos) << missing.err;
  EXPECT_NE(missing.err.find("none.urdf"), std::string::npos) << missing.err;
}

// Each misbehaviour flag of the mock headset executable gets a clear error (or a logged
// drop), and the server keeps serving other headsets.
TEST(ServerIntegration, MisbehavingHeadsetsDoNotHurtOthers) {
  ServerProcess server({.max_send_queue_bytes = 1u << 20});
  struct Case {
    std::string flag;
    std::string expected_output;
  };
  const std::vector<Case> cases{
      {"--corrupt-frame", "MALFORMED_MESSAGE"},
      {"--oversized-message", "MESSAGE_TOO_LARGE"},
      {"--never-read-replies", "dropped this session"},
      {"--disconnect-mid-upload", "disconnected mid-upload"},
      {"--protocol-version 2", "client speaks protocol version 2, this server speaks version 1"},
  };
  for (const auto& c : cases) {
    const std::string cmd = kMockPath + " --host 127.0.0.1 --port " + std::to_string(server.port()) +
                            " --batch-interval 0.01 --timeout 120 " + c.flag + " 2>&1";
    FILE* pipe = popen(cmd.c_str(), "r");
    ASSERT_NE(pipe, nullptr);
    std::string output;
    char buf[4096];
    while (std::fgets(buf, sizeof buf, pipe)) output += buf;
    const int status = pclose(pipe);
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) != 0) << c.flag << " exited 0:\n" << output;
    EXPECT_NE(output.find(c.expected_output), std::string::npos) << c.flag << ":\n" << output;
    ASSERT_TRUE(server.alive()) << "server died after " << c.flag;
    ExpectAnotherHeadsetSucceeds(server);
  }
  const std::string log = server.Log();
  EXPECT_NE(log.find("send queue limit"), std::string::npos) << "the drop of the non-reading client is logged";
  EXPECT_NE(log.find("client closed the connection"), std::string::npos);
}

TEST(ServerIntegration, SessionLimitIsAClearError) {
  ServerProcess server({.max_sessions = 2});
  ScriptedHeadset a(server), b(server);
  ASSERT_TRUE(a.Hello().has_hello_reply());
  ASSERT_TRUE(b.Hello().has_hello_reply());
  ScriptedHeadset c(server);  // connects (not counted yet); its Hello is refused
  const auto e = c.Hello();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_LIMIT_EXCEEDED);
  EXPECT_TRUE(e.error().fatal());
  EXPECT_NE(e.error().message().find("max_sessions"), std::string::npos) << e.error().message();
}

// ---------------------------------------------------------------- subscriptions

TEST(ServerIntegration, SubscribersReceiveResultsOfTheirRobot) {
  ServerProcess server;
  ScriptedHeadset watcher(server);
  ASSERT_TRUE(watcher.Hello().has_hello_reply());
  pb::ClientMessage sub;
  sub.mutable_subscribe()->set_robot_id("kr5");
  watcher.Send(sub);
  ASSERT_TRUE(watcher.Next().has_subscribed());
  HeadsetOptions o = Options(server);
  const HeadsetRun run = RunHeadset(Scene(1), o);
  ASSERT_TRUE(run.status.ok()) << run.status.ToString();
  const auto pushed = watcher.Await([](const pb::ServerMessage& m) { return m.has_result(); });
  EXPECT_EQ(pushed.result().session_id(), run.session_id);
  EXPECT_EQ(pushed.result().robot_id(), "kr5");
  EXPECT_EQ(pushed.result().status(), pb::RESULT_STATUS_OK);
}

// ---------------------------------------------------------------- shutdown

TEST(ServerIntegration, GracefulShutdownAnswersEveryAcceptedRequest) {
  ServerProcess server({.workers = 1, .queue_size = 16});
  std::vector<std::unique_ptr<ScriptedHeadset>> headsets;
  std::vector<std::set<std::uint64_t>> accepted(3);
  for (int i = 0; i < 3; ++i) {
    headsets.push_back(std::make_unique<ScriptedHeadset>(server));
    auto& h = *headsets.back();
    ASSERT_TRUE(h.Hello().has_hello_reply());
    h.Upload(Scene(1));
    h.Seed(Scene(1).seeds[static_cast<std::size_t>(i)]);
    h.Request(1);
    h.Request(2);
    for (int k = 0; k < 2; ++k)
      accepted[i].insert(h.Await([](const pb::ServerMessage& m) { return m.has_accepted(); }).accepted().request_id());
  }
  EXPECT_EQ(server.SignalAndWait(SIGTERM, 180), 0) << server.Log();
  int ok = 0, cancelled = 0;
  for (int i = 0; i < 3; ++i) {
    std::map<std::uint64_t, pb::ResultStatus> answers;
    bool shutdown_notice = false;
    for (const auto& m : headsets[i]->seen()) {  // results that came before the signal
      if (m.has_result()) answers[m.result().request_id()] = m.result().status();
    }
    while (true) {
      auto m = headsets[i]->Receive(30);
      if (!m.ok()) break;  // closed by the server after its last reply
      shutdown_notice |= m->has_shutdown();
      if (m->has_result()) answers[m->result().request_id()] = m->result().status();
    }
    EXPECT_TRUE(shutdown_notice) << "headset " << i;
    for (std::uint64_t id : accepted[i]) {
      ASSERT_TRUE(answers.count(id)) << "headset " << i << " request " << id << " lost";
      EXPECT_TRUE(answers[id] == pb::RESULT_STATUS_OK || answers[id] == pb::RESULT_STATUS_CANCELLED);
      ok += answers[id] == pb::RESULT_STATUS_OK;
      cancelled += answers[id] == pb::RESULT_STATUS_CANCELLED;
    }
  }
  EXPECT_GE(ok, 1) << "the running job finishes and delivers its result";
  EXPECT_GE(cancelled, 1) << "queued jobs are cancelled";
}

// ---------------------------------------------------------------- hardening

long StatusKb(pid_t pid, const std::string& key) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(in, line);)
    if (line.rfind(key + ":", 0) == 0) return std::stol(line.substr(key.size() + 1));
  return -1;
}

// A flat n x n grid (2 (n-1)^2 triangles), far from any robot.
pb::ClientMessage GridSurface(std::uint64_t id, int n) {
  Surface s;
  s.id = id;
  s.T_world_surface = Iso3(Eigen::Translation3d(50, 50, 0));
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) s.mesh.vertices.emplace_back(0.01f * x, 0.01f * y, 0.0f);
  for (int y = 0; y + 1 < n; ++y)
    for (int x = 0; x + 1 < n; ++x) {
      const auto v = static_cast<std::uint32_t>(y * n + x), u = static_cast<std::uint32_t>(n);
      s.mesh.triangles.push_back({v, v + 1, v + u});
      s.mesh.triangles.push_back({v + 1, v + u + 1, v + u});
    }
  pb::ClientMessage m;
  *m.mutable_surface_upsert() = wire::SurfaceToProto(s, FrameConvention::kUnity);
  return m;
}

pb::ClientMessage PingMessage(std::uint64_t nonce) {
  pb::ClientMessage m;
  m.mutable_ping()->set_nonce(nonce);
  return m;
}

// Sends the surfaces then a Ping, and collects the errors that come before its Pong.
std::vector<pb::Error> SendSurfaces(ScriptedHeadset& h, pb::ClientMessage surface, std::uint64_t first_id, int count) {
  for (int k = 0; k < count; ++k) {
    surface.mutable_surface_upsert()->set_surface_id(first_id + static_cast<std::uint64_t>(k));
    h.Send(surface);
  }
  h.Send(PingMessage(first_id));
  std::vector<pb::Error> errors;
  h.Await([&](const pb::ServerMessage& m) {
    if (m.has_error()) errors.push_back(m.error());
    return m.has_pong() && m.pong().nonce() == first_id;
  });
  return errors;
}

bool Names(const pb::Error& e, const std::string& what) { return e.message().find(what) != std::string::npos; }

// Every session tries to take more memory than the server has: each gets LIMIT_EXCEEDED
// naming the limit or the budget, keeps what it had, an accepted request still completes, and
// once memory is freed the same session and a new one register.
TEST(ServerHardening, MemoryBudgetAndTriangleLimitRefuseWithoutHurtingSessions) {
  constexpr std::size_t kBudget = 256u << 20;
  ServerProcess server({.workers = 1,
                        .limits_yaml = "  memory_budget_bytes: " + std::to_string(kBudget) +
                                       "\n  max_triangles_per_session: 7500000\n  max_message_bytes: 33554432\n"});
  ScriptedHeadset a(server);
  const auto hello = a.Hello();
  ASSERT_TRUE(hello.has_hello_reply());
  EXPECT_EQ(hello.hello_reply().limits().memory_budget_bytes(), kBudget);
  EXPECT_EQ(hello.hello_reply().limits().max_triangles_per_session(), 7500000u);
  a.Upload(Scene(1));
  a.Seed(Scene(1).seeds[0]);
  // 7,500,001 triangles on three vertices (the shape that once took 1.2 GB): refused by count
  // before anything is converted.
  pb::ClientMessage many;
  auto* u = many.mutable_surface_upsert();
  u->set_surface_id(777);
  u->set_frame(pb::FRAME_CONVENTION_UNITY);
  for (int k = 0; k < 9; ++k) u->add_vertices(k == 3 || k == 7 ? 1.0f : 0.0f);
  *u->mutable_t_world_surface() = wire::PoseToProto(Iso3::Identity(), FrameConvention::kUnity);
  for (int k = 0; k < 7500001; ++k) u->add_triangles(0), u->add_triangles(1), u->add_triangles(2);
  auto errors = SendSurfaces(a, many, 777, 1);
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_EQ(errors[0].code(), pb::ERROR_CODE_LIMIT_EXCEEDED);
  EXPECT_EQ(errors[0].surface_id(), 777u);
  EXPECT_FALSE(errors[0].fatal());
  EXPECT_TRUE(Names(errors[0], "max_triangles_per_session")) << errors[0].message();
  // A first registration builds the robot's model cache (the server's fixed part, not charged).
  a.Request(10);
  ASSERT_EQ(a.AwaitResult(10).result().status(), pb::RESULT_STATUS_OK);
  const long rss_before_kb = server.RssKb();
  a.Request(1);  // accepted now, so its memory is reserved before the others flood
  a.Await([](const pb::ServerMessage& m) { return m.has_accepted() && m.accepted().request_id() == 1; });

  // Three sessions each send 13 surfaces of 300k vertices and 597k triangles (10.8 MB held,
  // 9 MB frames): the 13th is over the session's triangles, and the budget cannot hold them all.
  std::vector<std::unique_ptr<ScriptedHeadset>> floods;
  const pb::ClientMessage big = GridSurface(0, 548);
  int budget_errors = 0, accepted_big = 0;
  for (int f = 0; f < 3; ++f) {
    floods.push_back(std::make_unique<ScriptedHeadset>(server));
    ASSERT_TRUE(floods.back()->Hello().has_hello_reply());
    errors = SendSurfaces(*floods.back(), big, 1, 13);
    if (f == 0) {
      ASSERT_EQ(errors.size(), 1u);
      EXPECT_EQ(errors[0].surface_id(), 13u);
      EXPECT_TRUE(Names(errors[0], "max_triangles_per_session")) << errors[0].message();
      errors.clear();
    }
    for (const auto& e : errors) {
      EXPECT_EQ(e.code(), pb::ERROR_CODE_LIMIT_EXCEEDED) << e.message();
      EXPECT_FALSE(e.fatal());
      budget_errors += Names(e, "memory_budget_bytes");
    }
    accepted_big += 13 - static_cast<int>(errors.size()) - (f == 0);
  }
  EXPECT_GT(budget_errors, 0) << "38 x 10.8 MB cannot fit a 256 MiB budget";
  EXPECT_EQ(a.AwaitResult(1).result().status(), pb::RESULT_STATUS_OK) << "the request accepted before is not hurt";
  // A fourth session fills what is left with small surfaces (20k vertices, 0.7 MB) until the
  // budget refuses them too.
  floods.push_back(std::make_unique<ScriptedHeadset>(server));
  ASSERT_TRUE(floods.back()->Hello().has_hello_reply());
  errors = SendSurfaces(*floods.back(), GridSurface(0, 142), 100, 150);
  ASSERT_FALSE(errors.empty());
  for (const auto& e : errors) EXPECT_TRUE(Names(e, "memory_budget_bytes")) << e.message();
  const long hwm_kb = StatusKb(server.pid(), "VmHWM"), rss_kb = server.RssKb();
  std::printf("memory budget %zu MiB: %d of 38 big surfaces held; RSS %.1f MiB before the flood, %.1f MiB after, "
              "peak %.1f MiB (growth %.1f MiB)\n", kBudget >> 20, accepted_big, rss_before_kb / 1024.0,
              rss_kb / 1024.0, hwm_kb / 1024.0, (hwm_kb - rss_before_kb) / 1024.0);
  RecordProperty("rss_before_mb", static_cast<int>(rss_before_kb / 1024));
  RecordProperty("rss_peak_mb", static_cast<int>(hwm_kb / 1024));
  // Clients' memory is charged at its real size, so a full budget is about the budget in RSS;
  // the allowance is for the allocator's and the sessions' bookkeeping, which is not charged.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
  // ASan's redzones and freed-memory quarantine, and TSan's shadow memory and allocator (1.3 GB
  // over the same flood), are not the server's: RSS says nothing here.
  std::printf("(sanitizer build: the RSS bound is not checked)\n");
#else
  EXPECT_LT(hwm_kb - rss_before_kb, static_cast<long>((kBudget + kBudget / 16) >> 10))
      << "what clients add stays within the budget";
#endif

  // A's next request does not fit: a clear error naming the budget and the request.
  a.Request(2);
  auto e = a.AwaitError();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_LIMIT_EXCEEDED);
  EXPECT_EQ(e.error().request_id(), 2u);
  EXPECT_TRUE(Names(e.error(), "memory_budget_bytes")) << e.error().message();
  EXPECT_TRUE(Names(e.error(), "request 2")) << e.error().message();
  // A flood leaves; A, which kept its surfaces, registers again, and so does a new session.
  floods.front()->Close();
  std::uint64_t id = 3;
  for (int tries = 0; tries < 200; ++tries, ++id) {
    a.Request(id);
    const auto m = a.Await([id](const pb::ServerMessage& x) {
      return (x.has_accepted() && x.accepted().request_id() == id) || (x.has_error() && x.error().request_id() == id);
    });
    if (m.has_accepted()) break;
    ASSERT_TRUE(Names(m.error(), "memory_budget_bytes")) << m.error().message();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));  // the closed session's memory is freed on its strand
  }
  const auto r = a.AwaitResult(id).result();
  EXPECT_EQ(r.status(), pb::RESULT_STATUS_OK) << r.message();
  EXPECT_GT(r.scene_triangles(), 1000u) << "A's surfaces are all still there";
  ExpectAnotherHeadsetSucceeds(server);
  EXPECT_TRUE(server.alive());
}

// A raw TCP connection from a chosen loopback address (the per-peer cap counts addresses).
int ConnectFrom(const std::string& source, std::uint16_t port) {
  const int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in local{};
  local.sin_family = AF_INET;
  inet_pton(AF_INET, source.c_str(), &local.sin_addr);
  sockaddr_in remote{};
  remote.sin_family = AF_INET;
  remote.sin_port = htons(port);
  inet_pton(AF_INET, "127.0.0.1", &remote.sin_addr);
  if (bind(fd, reinterpret_cast<sockaddr*>(&local), sizeof local) != 0 ||
      connect(fd, reinterpret_cast<sockaddr*>(&remote), sizeof remote) != 0) {
    close(fd);
    return -1;
  }
  return fd;
}

// The first server message on a raw socket, or none if it closes (or timeout_s passes) first.
std::optional<pb::ServerMessage> FirstMessage(int fd, double timeout_s) {
  wire::FrameDecoder rx(1 << 20);
  const auto deadline = Clock::now() + std::chrono::duration<double>(timeout_s);
  while (Clock::now() < deadline) {
    pollfd p{fd, POLLIN, 0};
    if (poll(&p, 1, 100) <= 0) continue;
    const auto space = rx.Buffer(4096);
    const ssize_t n = read(fd, space.data(), space.size());
    if (n <= 0) return std::nullopt;
    rx.Commit(static_cast<std::size_t>(n));
    const auto f = rx.Next();
    if (f.kind != wire::FrameDecoder::Frame::Kind::kFrame) continue;
    pb::ServerMessage m;
    if (m.ParseFromArray(f.body.data(), static_cast<int>(f.body.size()))) return m;
    return std::nullopt;
  }
  return std::nullopt;
}

// Hundreds of connections that never say Hello (half of them send a byte of a frame) do not
// keep a well-behaved headset out; each is closed with HANDSHAKE_TIMEOUT, one peer's ninth is
// refused, and a client trickling a frame after Hello is closed by the frame deadline.
TEST(ServerHardening, IdleAndTricklingConnectionsDoNotLockOutHeadsets) {
  rlimit files{};
  getrlimit(RLIMIT_NOFILE, &files);
  files.rlim_cur = std::min<rlim_t>(files.rlim_max, 8192);
  setrlimit(RLIMIT_NOFILE, &files);  // the server inherits it
  constexpr int kPerPeer = 8;
  const int attackers = static_cast<int>(std::min<rlim_t>(1000, (files.rlim_cur - 64) / 2));
  ServerProcess server({.max_sessions = 4,
                        .max_connections_per_peer = kPerPeer,
                        .server_yaml = "  hello_timeout_s: 3\n  frame_timeout_s: 2\n",
                        .limits_yaml = "  max_pending_connections: 64\n"});
  const auto source = [](int i) {
    const int peer = i / kPerPeer;
    return "127.1." + std::to_string(peer / 250) + "." + std::to_string(peer % 250 + 1);
  };
  std::vector<int> fds;
  for (int i = 0; i < attackers; ++i) {
    const int fd = ConnectFrom(source(i), server.port());
    ASSERT_GE(fd, 0) << "connection " << i << " from " << source(i) << ": " << std::strerror(errno);
    if (i % 2 == 1) {
      ASSERT_EQ(write(fd, "\x0a", 1), 1);  // a frame of 10 bytes begins, and stops
    }
    fds.push_back(fd);
  }
  // A fresh peer's ninth connection (newer than the flood, so none of its eight is evicted).
  std::vector<int> peer_fds;
  for (int k = 0; k < kPerPeer; ++k) {
    peer_fds.push_back(ConnectFrom("127.2.0.1", server.port()));
    ASSERT_GE(peer_fds.back(), 0);
  }
  const int extra = ConnectFrom("127.2.0.1", server.port());
  ASSERT_GE(extra, 0);

  // The good headset, right behind the flood.
  const auto t0 = Clock::now();
  ScriptedHeadset good(server);
  const auto reply = good.Hello();
  const double hello_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  ASSERT_TRUE(reply.has_hello_reply()) << reply.DebugString();
  good.Upload(Scene(1));
  good.Seed(Scene(1).seeds[0]);
  good.Request(1);
  const auto result = good.AwaitResult(1).result();
  const double registered_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  EXPECT_EQ(result.status(), pb::RESULT_STATUS_OK) << result.message();

  const auto refused = FirstMessage(extra, 30);
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ(refused->error().code(), pb::ERROR_CODE_LIMIT_EXCEEDED);
  EXPECT_TRUE(Names(refused->error(), "max_connections_per_peer")) << refused->error().message();
  close(extra);
  for (int fd : peer_fds) close(fd);

  // A session that trickles a frame is closed by the frame deadline.
  auto trickler = Connection::Connect("127.0.0.1", server.port(), 30);
  ASSERT_TRUE(trickler.ok());
  pb::ClientMessage hi;
  hi.mutable_hello()->set_protocol_version(wire::kProtocolVersion);
  ASSERT_TRUE(trickler->Send(hi).ok());
  ASSERT_TRUE(trickler->Receive(30)->has_hello_reply());
  for (const char byte : std::string("\x0a\x0a\x08\x01", 4)) {
    if (!trickler->SendRaw(std::string(1, byte)).ok()) break;  // closed already
    std::this_thread::sleep_for(std::chrono::milliseconds(700));
  }
  const auto timed_out = trickler->Receive(30);
  ASSERT_TRUE(timed_out.ok()) << timed_out.status().ToString();
  EXPECT_EQ(timed_out->error().code(), pb::ERROR_CODE_FRAME_TIMEOUT);
  EXPECT_TRUE(timed_out->error().fatal());
  EXPECT_TRUE(Names(timed_out->error(), "frame_timeout_s")) << timed_out->error().message();

  // Every idle connection was closed before Hello: evicted by newer ones, out of time, or (the
  // tricklers) by the frame deadline, which is shorter here.
  int handshake_closed = 0, evicted = 0, frame_closed = 0;
  for (std::size_t k = 0; k < fds.size(); ++k) {
    const auto m = FirstMessage(fds[k], 30);
    const pb::ErrorCode code = m ? m->error().code() : pb::ERROR_CODE_UNSPECIFIED;
    if (code == pb::ERROR_CODE_HANDSHAKE_TIMEOUT) {
      ++handshake_closed;
      evicted += Names(m->error(), "max_pending_connections");
    } else if (code == pb::ERROR_CODE_FRAME_TIMEOUT && k % 2 == 1) {
      ++frame_closed;
    } else {
      ADD_FAILURE() << "connection " << k << ": " << (m ? m->DebugString() : "closed without a message");
    }
    close(fds[k]);
  }
  EXPECT_EQ(handshake_closed + frame_closed, attackers);
  EXPECT_GT(evicted, 0);
  std::printf("%d idle/trickling connections from %d addresses (%d evicted, %d out of time, %d frame deadline): the "
              "good headset's HelloReply after %.0f ms, its Result after %.0f ms\n", attackers,
              (attackers + kPerPeer - 1) / kPerPeer, evicted, handshake_closed - evicted, frame_closed, hello_ms,
              registered_ms);
  RecordProperty("connections", attackers);
  RecordProperty("hello_ms", static_cast<int>(hello_ms));
  RecordProperty("registered_ms", static_cast<int>(registered_ms));
  EXPECT_TRUE(server.alive());
}

// A surface's Error comes before the Pong of a later Ping; bad ids and enums get clear errors;
// a client that half-closes after its request still gets the Result.
TEST(ServerHardening, OrderingHalfCloseAndStrictFields) {
  ServerProcess server;
  ScriptedHeadset h(server);
  const auto hello = h.Hello();
  ASSERT_TRUE(hello.has_hello_reply());
  const pb::Limits& limits = hello.hello_reply().limits();
  EXPECT_EQ(limits.max_sessions(), 64u);
  EXPECT_EQ(limits.max_message_bytes(), 16u << 20);
  EXPECT_EQ(limits.max_requests_per_session(), 8u);
  EXPECT_GT(limits.max_triangles_per_session(), 0u);
  EXPECT_DOUBLE_EQ(limits.hello_timeout_s(), 5.0);
  ASSERT_EQ(limits.params_size(), 4);
  EXPECT_EQ(limits.params(0).name(), "crop_radius_m");
  EXPECT_DOUBLE_EQ(limits.params(0).max(), 50.0);
  h.Upload(Scene(1));
  Surface bad = Scene(1).surfaces.front();
  bad.id = 5555;
  bad.mesh.vertices[0].x() = std::nanf("");
  pb::ClientMessage m;
  *m.mutable_surface_upsert() = wire::SurfaceToProto(bad, FrameConvention::kUnity);
  h.Send(m);
  h.Send(PingMessage(9));
  auto first = h.Next();
  ASSERT_TRUE(first.has_error()) << first.DebugString();
  EXPECT_EQ(first.error().surface_id(), 5555u);
  EXPECT_EQ(h.Next().pong().nonce(), 9u) << "the Pong comes after the surface's Error";
  // Out-of-range enums, everywhere a frame is named.
  pb::ClientMessage seed;
  *seed.mutable_seed_pose()->mutable_t_world_seed() = wire::PoseToProto(Scene(1).seeds[0], FrameConvention::kUnity);
  seed.mutable_seed_pose()->set_frame(static_cast<pb::FrameConvention>(99));
  h.Send(seed);
  auto e = h.Next();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_TRUE(Names(e.error(), "frame convention 99")) << e.error().message();
  h.Seed(Scene(1).seeds[0]);
  pb::ClientMessage req;
  req.mutable_register_request()->set_request_id(4);
  req.mutable_register_request()->set_robot_id("kr5");
  req.mutable_register_request()->set_result_frame(static_cast<pb::FrameConvention>(99));
  h.Send(req);
  e = h.Next();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_EQ(e.error().request_id(), 4u);
  EXPECT_TRUE(Names(e.error(), "RegisterRequest.result_frame: frame convention 99")) << e.error().message();
  // request_id 0 cannot be told from unset in the answer: refused.
  h.Request(0);
  e = h.Next();
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT);
  EXPECT_TRUE(Names(e.error(), "request_id must be >= 1")) << e.error().message();
  // Half-close after the request: the Result still arrives, then the server closes.
  h.Request(1);
  h.ShutdownWrite();
  bool accepted = false;
  std::optional<pb::Result> result;
  while (true) {
    auto next = h.Receive(kReplyTimeout);
    if (!next.ok()) {
      EXPECT_EQ(next.status().code(), StatusCode::kUnavailable) << next.status().ToString();
      break;
    }
    accepted |= next->has_accepted();
    if (next->has_result()) result = next->result();
  }
  EXPECT_TRUE(accepted);
  ASSERT_TRUE(result.has_value()) << "the half-closed client's Result was lost";
  EXPECT_EQ(result->status(), pb::RESULT_STATUS_OK) << result->message();
  EXPECT_NE(server.Log().find("every result delivered"), std::string::npos);
}

// ---------------------------------------------------------------- continuous referencing

// The settled updates of a run (SettledUpdates) and how many of them lie within ADD 10 mm.
std::pair<int, int> SettledWithin10mm(const TrackHeadsetRun& run) {
  const std::vector<bool> settled = SettledUpdates(run);
  int scored = 0, within = 0;
  for (std::size_t i = 0; i < run.updates.size(); ++i) {
    if (!settled[i]) continue;
    ++scored;
    within += run.updates[i].add_mm < 10;
  }
  return {scored, within};
}

// A tracking run that went through (no error from the server) and kept at least 90 % of its
// settled updates, at least 10 of them, within ADD 10 mm. Call with ASSERT_NO_FATAL_FAILURE.
void ExpectMostSettledWithin10mm(const TrackHeadsetRun& run, const std::string& context = "") {
  ASSERT_TRUE(run.status.ok()) << context << run.status.ToString();
  for (const auto& e : run.errors) ADD_FAILURE() << context << "server error: " << e.message();
  const auto [scored, within] = SettledWithin10mm(run);
  ASSERT_GE(scored, 10) << context;
  EXPECT_GE(within, 0.9 * scored) << context << within << " of " << scored << " updates within 10 mm";
}

// A headset streams simulated depth frames in real time through the server, a robot-side
// session streams the joints on its own clock, a third session subscribes: every frame is
// answered or counted as dropped, the filtered pose follows the truth through the world jump.
TEST(ServerIntegration, TrackingStreamsUpdatesThroughAWorldJump) {
  ServerProcess server;
  TrackHeadsetOptions o;
  o.port = server.port();
  // Long enough that a server dropping most frames (a sanitized build on a loaded machine: 60-74
  // of 120 frames in 4 s) still processes a second's worth on each side of the jump and then some
  // (SettledUpdates).
  o.duration_s = 8.0;
  o.jump_at_s = 4.0;
  o.rng_seed = 5;
  const TrackHeadsetRun run = RunTrackingHeadset(o);
  ASSERT_TRUE(run.status.ok()) << run.status.ToString();
  for (const auto& e : run.errors) ADD_FAILURE() << "server error: " << e.message();
  EXPECT_EQ(run.frames_sent, 240);
  EXPECT_EQ(static_cast<std::uint64_t>(run.updates.size()) + run.frames_dropped, 240u);
  EXPECT_LT(std::abs(run.reported_offset_error_s), 0.005) << "the headset's clock offset, from round trips";
  int scored = 0, within = 0;
  std::ostringstream misses;  // names the updates off by 10 mm or more, to tell a slow recovery from drift
  std::vector<double> latency, server_latency;
  const std::vector<bool> settled = SettledUpdates(run);
  for (std::size_t i = 0; i < run.updates.size(); ++i) {
    const TrackUpdateRecord& u = run.updates[i];
    // The frame's exposure in Unix time (what the ROS bridge stamps with), through the
    // headset's clock offset: within the clock estimate's error.
    EXPECT_LT(std::abs(u.unix_time_error_s), 0.005) << "frame " << u.frame_id;
    latency.push_back(u.latency_ms);
    server_latency.push_back(u.server_latency_ms);
    if (!settled[i]) continue;
    ++scored;
    if (u.add_mm < 10) ++within;
    else misses << " [frame " << u.frame_id << " at " << u.true_time_s << " s, " << u.state << ", " << u.add_mm << " mm]";
  }
  // About 200 when the server keeps up; 20 when it drops two frames in three (ASan beside six
  // busy loops on its core).
  ASSERT_GE(scored, 10);
  EXPECT_GE(within, 0.9 * scored) << within << " of " << scored << " updates within 10 mm; off:" << misses.str();
  // The long-throw camera's 1 % of range, as the server measures it from the frames.
  EXPECT_NEAR(run.updates.back().depth_noise, 0.0105, 0.001);
  std::sort(latency.begin(), latency.end());
  std::sort(server_latency.begin(), server_latency.end());
  // Client side: frame sent -> update read (the client reads between rendering frames, so
  // this includes up to one frame's simulation); server side: frame received -> update sent.
  std::printf("tracking through the server: %zu updates, %llu dropped, latency client median %.1f p95 %.1f ms, "
              "server median %.1f p95 %.1f ms\n",
              run.updates.size(), static_cast<unsigned long long>(run.frames_dropped), latency[latency.size() / 2],
              latency[latency.size() * 95 / 100], server_latency[server_latency.size() / 2],
              server_latency[server_latency.size() * 95 / 100]);
  EXPECT_EQ(run.subscriber_updates, static_cast<int>(run.updates.size())) << "the subscriber sees every update";
}

// A device that stamps its camera poses 60 ms after the exposure and says so in its
// TrackRequest: the server takes each frame's camera back to its exposure. Not told, the same
// stream kept 114 of 150 settled updates within 10 mm (Tracker.TakesALateCameraPoseBackToTheExposure:
// a median ADD of 9 mm against 3 mm told).
TEST(ServerIntegration, TrackingTakesADeclaredCameraPoseLatency) {
  ServerProcess server;
  TrackHeadsetOptions o;
  o.port = server.port();
  o.duration_s = 6.0;
  o.jump_at_s = 100.0;  // none
  o.rng_seed = 5;
  o.pose_latency_s = 0.06;
  o.declare_latency = true;
  o.subscriber = false;
  ASSERT_NO_FATAL_FAILURE(ExpectMostSettledWithin10mm(RunTrackingHeadset(o)));
}

// A wrapped (AHAT) stream, 512x512 at 45 fps, through the real server: followed within 10 mm,
// and its depth noise measured and reported as for long-throw streams (docs/tracking.md, "Wrapped
// depth's noise"): the simulated AHAT noise is 0.3 % of range + 2 mm, about 0.5 % at arm's length,
// and a 2 % sensor reads about 2.2 %.
TEST(ServerIntegration, TrackingAWrappedStreamReportsItsNoise) {
  ServerProcess server;
  for (const double noise : {0.0, 0.02}) {
    TrackHeadsetOptions o;
    o.port = server.port();
    o.kind = "ahat";
    o.duration_s = 5.0;  // a sanitized server drops most 512x512 frames: 5 s leaves it enough
    o.jump_at_s = 100.0;  // none
    o.rng_seed = 3;
    o.depth_noise_fraction = noise;
    o.subscriber = false;
    const TrackHeadsetRun run = RunTrackingHeadset(o);
    ASSERT_NO_FATAL_FAILURE(ExpectMostSettledWithin10mm(run, "noise " + std::to_string(noise) + ": "));
    const double expected = noise > 0 ? noise + 0.002 / 1.2 : 0.003 + 0.002 / 1.2;
    EXPECT_NEAR(run.updates.back().depth_noise, expected, 0.25 * expected) << "noise " << noise;
  }
}

// Frames sent faster than they are processed: the newest wins, the rest are dropped and
// counted, and nothing queues up.
TEST(ServerIntegration, TrackingDropsOldestFramesUnderABurst) {
  ServerProcess server;
  TrackHeadsetOptions o;
  o.port = server.port();
  o.duration_s = 2.0;
  o.jump_at_s = 100.0;
  o.burst = 10;
  o.subscriber = false;
  const TrackHeadsetRun run = RunTrackingHeadset(o);
  ASSERT_TRUE(run.status.ok()) << run.status.ToString();
  EXPECT_EQ(run.frames_sent, 60);
  EXPECT_GT(run.frames_dropped, 0u);
  EXPECT_EQ(static_cast<std::uint64_t>(run.updates.size()) + run.frames_dropped, 60u);
  // The updates come in frame order: a dropped frame is never processed late.
  for (std::size_t i = 1; i < run.updates.size(); ++i) EXPECT_GT(run.updates[i].frame_id, run.updates[i - 1].frame_id);
}

TEST(ServerIntegration, TrackingErrorsAreClearAndKeepTheSession) {
  ServerProcess server;
  ScriptedHeadset h(server);
  ASSERT_TRUE(h.Hello().has_hello_reply());
  pb::ClientMessage frame;
  frame.mutable_depth_frame()->set_robot_id("kr5");
  frame.mutable_depth_frame()->set_width(4);
  frame.mutable_depth_frame()->set_height(2);
  frame.mutable_depth_frame()->set_fx(10), frame.mutable_depth_frame()->set_fy(10);
  frame.mutable_depth_frame()->set_depth_mm(std::string(16, '\1'));
  frame.mutable_depth_frame()->set_frame(pb::FRAME_CONVENTION_ROS);
  frame.mutable_depth_frame()->mutable_t_world_camera()->mutable_orientation()->set_w(1);
  frame.mutable_depth_frame()->mutable_t_world_camera()->mutable_position()->set_z(1);
  h.Send(frame);
  auto e = h.Await([](const pb::ServerMessage& m) { return m.has_error(); });
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_NOT_TRACKING) << e.error().message();
  frame.mutable_depth_frame()->set_depth_mm(std::string(15, '\1'));
  h.Send(frame);
  e = h.Await([](const pb::ServerMessage& m) { return m.has_error(); });
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_BAD_DEPTH_FRAME);
  EXPECT_NE(e.error().message().find("15 bytes"), std::string::npos) << e.error().message();
  pb::ClientMessage track;
  track.mutable_track_request()->set_robot_id("nope");
  h.Send(track);
  e = h.Await([](const pb::ServerMessage& m) { return m.has_error(); });
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_UNKNOWN_ROBOT);
  track.mutable_track_request()->set_robot_id("kr5");
  track.mutable_track_request()->set_result_frame(pb::FRAME_CONVENTION_ROS);
  h.Send(track);
  e = h.Await([](const pb::ServerMessage& m) { return m.has_error(); });
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_NO_SEED);
  track.mutable_track_request()->mutable_seed()->set_frame(pb::FRAME_CONVENTION_ROS);
  track.mutable_track_request()->mutable_seed()->mutable_t_world_seed()->mutable_orientation()->set_w(1);
  track.mutable_track_request()->mutable_seed()->mutable_t_world_seed()->mutable_position()->set_x(1);
  track.mutable_track_request()->set_camera_pose_latency_s(-0.5);
  h.Send(track);
  e = h.Await([](const pb::ServerMessage& m) { return m.has_error(); });
  EXPECT_EQ(e.error().code(), pb::ERROR_CODE_INVALID_ARGUMENT) << e.error().message();
  EXPECT_NE(e.error().message().find("camera pose latency -0.5 s"), std::string::npos) << e.error().message();
  pb::ClientMessage ping;
  ping.mutable_ping()->set_nonce(7);
  ping.mutable_ping()->set_client_time_s(3.5);
  h.Send(ping);
  const auto pong = h.Await([](const pb::ServerMessage& m) { return m.has_pong(); });
  EXPECT_EQ(pong.pong().client_time_s(), 3.5);
  EXPECT_LE(pong.pong().receive_time_s(), pong.pong().server_time_s());
}

// Joints that move while the map is made smear the arm's mesh: the one-shot result says so, and
// rests on the links that stood still when they fix the heading on this map's resolution
// (ChooseMovingFit: a moving first joint leaves only the base, a moving second joint the turret
// too). With most of the arm moving, no fit on that map is OK.
TEST(ServerIntegration, ResultSaysWhenTheJointsMovedWhileMappingAndWhatTheFitRestedOn) {
  ServerProcess server;
  const HeadsetScene scene = Scene(1);
  TriangleMesh map;
  for (const Surface& s : scene.surfaces) map.Append(s.mesh, s.T_world_surface);
  ASSERT_OK_AND_ASSIGN(const RobotModel robot, RobotModel::Load(testing::BuiltinRobotUrdf()));
  for (const auto& [joint, moved] : std::vector<std::pair<std::string, double>>{
           {"joint_a1", 0.0}, {"joint_a1", 0.3}, {"joint_a2", 0.3}}) {
    SCOPED_TRACE(joint + " moved by " + std::to_string(moved));
    ScriptedHeadset h(server);
    ASSERT_TRUE(h.Hello().has_hello_reply());
    h.Upload(scene);
    for (const double q : {0.1, 0.1 + moved}) {
      pb::ClientMessage j;
      j.mutable_joint_state()->set_robot_id("kr5");
      j.mutable_joint_state()->add_names(joint);
      j.mutable_joint_state()->add_positions(q);
      h.Send(j);
    }
    h.Seed(scene.seeds[0]);
    h.Request(1);
    const auto r = h.Await([](const pb::ServerMessage& m) { return m.has_result(); });
    const pb::Result& result = r.result();
    EXPECT_EQ(result.joints_moved_while_mapping(), moved > 0) << result.message();
    EXPECT_NEAR(result.joint_motion_rad(), moved, 1e-9);
    if (moved == 0) {
      EXPECT_EQ(result.fitted_links_size(), 0);
      continue;
    }
    EXPECT_NE(result.message().find("moved by up to 0.3 rad"), std::string::npos) << result.message();
    ASSERT_OK_AND_ASSIGN(const MovingFit rule,
                         ChooseMovingFit(robot, {{joint, 0.1 + moved}}, {{joint, {0.1, 0.1 + moved}}},
                                         kJointMotionWhileMappingRad, MedianEdgeLength(map), kMovingFitMinLeverageVoxels,
                                         kMovingFitMinMovedShare));
    const std::set<std::string> fitted(result.fitted_links().begin(), result.fitted_links().end());
    EXPECT_EQ(fitted, rule.links.value_or(std::set<std::string>{})) << result.message();
    if (joint == "joint_a2") {
      EXPECT_TRUE(rule.unmoved.contains("link_1")) << "the turret stands still when joint_a2 moves";
    }
    RecordProperty(joint + "_fitted_links", static_cast<int>(fitted.size()));
    if (rule.links) {
      EXPECT_NE(result.message().find("the fit rests on the links that did not move"), std::string::npos) << result.message();
    } else {
      EXPECT_NE(result.message().find("the fit rests on the whole model"), std::string::npos) << result.message();
    }
    ASSERT_TRUE(rule.much_moved) << "the first and the second joint carry most of the arm";
    EXPECT_NE(result.status(), pb::RESULT_STATUS_OK) << result.message();
  }
}

}  // namespace
}  // namespace arref::headset
