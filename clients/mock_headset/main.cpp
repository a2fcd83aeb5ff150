// arref-mock-headset: plays a HoloLens app against arref-server (see headset_client.h).
// Exit code 0 only when every registration came back OK.
#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <map>
#include <thread>
#include <nlohmann/json.hpp>

#include "arref/base/stats.h"
#include "headset_client.h"
#include "track_client.h"
#include "client_io.h"

namespace {

using namespace arref;
using namespace arref::headset;
using Clock = std::chrono::steady_clock;

struct Args {
  HeadsetOptions options;
  int port = 7311;
  std::uint64_t rng_seed = 1;
  std::string scene;
  std::string frame = "ros";
  std::string truth;
  std::string truth_robot;
  RobotLoadOptions truth_robot_load;
  std::string seed;
  int clients = 1;
  bool json = false;
  bool disconnect = false, corrupt = false, oversized = false, never_read = false;
  double soak_s = 0;  // > 0: soak mode (scripts/soak.sh)
  int bad_every = 5;
  std::string log_level = "warn";
  std::string recording;
  bool fast = false;
  bool track = false;
  TrackHeadsetOptions track_options;
  bool room = false;  // map a whole simulated room and ask with no seed
  int room_arms = 1;
  std::string room_mesher = "own";
};

void AddFlags(CLI::App& app, Args& a) {
  HeadsetOptions& o = a.options;
  app.add_option("--host", o.host, "Server address")->capture_default_str();
  app.add_option("--port", a.port, "Server port")->capture_default_str()->check(CLI::Range(1, 65535));
  app.add_option("--robot", o.robot_id, "Robot id served by the server")->capture_default_str();
  app.add_option("--rng-seed", a.rng_seed, "Simulated cell (built-in robot, small preset) to map")->capture_default_str();
  app.add_option("--scene", a.scene, "Map this mesh file instead of a simulated cell");
  app.add_option("--frame", a.frame, "Convention of --scene and --seed: ros or unity")
      ->check(CLI::IsMember({"ros", "unity"}))->capture_default_str();
  app.add_option("--truth", a.truth, "Ground truth JSON of --scene (from `arref simulate`)");
  app.add_option("--truth-robot", a.truth_robot,
                 "URDF of the robot the --truth cell was simulated with, for its errors (default: the built-in robot)");
  app.add_option("--package-path", a.truth_robot_load.package_path,
                 "Folder holding ROS packages for --truth-robot's package:// URIs (repeatable)");
  app.add_option("--seed", a.seed, "Seed pose x,y,z,qx,qy,qz,qw for --scene");
  app.add_option("--seed-index", o.seed_index, "Which of the cell's seeds the user places")->capture_default_str();
  app.add_option("--batches", o.batches, "Upload the map in this many batches")->capture_default_str();
  app.add_option("--batch-interval", o.batch_interval_s, "Seconds between batches")->capture_default_str();
  app.add_option("--resend-fraction", o.resend_fraction, "Share of the first batch re-sent as updates");
  app.add_option("--quantize", o.quantize_scale, "Send int16 vertices with this step, m (0: floats)");
  app.add_option("--method", o.method, "Registration method (default: the server's)");
  app.add_flag("!--no-head-path", o.send_head_path,
               "Do not send where the wearer walked while mapping (RegisterRequest.head_path)");
  app.add_option("--repeat", o.repeat, "Registrations per headset")->capture_default_str();
  app.add_flag("--new-seed-each-repeat", o.new_seed_each_repeat,
               "Each registration after the first moves the seed to the scene's next one (a new crop each time; "
               "also in --soak)");
  app.add_option("--clients", a.clients, "Concurrent headsets (latency figures)")->capture_default_str();
  app.add_option("--timeout", o.timeout_s, "Give up waiting for a reply after this many seconds");
  app.add_option("--name", o.client_name, "Client name sent in Hello");
  app.add_option("--auth-token", o.auth_token, "Token if the server requires one");
  app.add_flag("--tls", o.tls.enabled, "Connect over TLS, verifying the server against the system's trusted CAs");
  app.add_option("--tls-ca", o.tls.ca_file,
                 "Connect over TLS, verifying the server's certificate against this PEM CA (and its name against --host)")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-server-name", o.tls.server_name,
                 "The name the server's certificate must carry, when --host is another (e.g. an IP address)");
  app.add_option("--tls-cert", o.tls.certificate, "Our own certificate (PEM), for a server with tls.client_ca")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-key", o.tls.private_key, "The private key of --tls-cert (PEM)")->check(CLI::ExistingFile);
  app.add_option("--protocol-version", o.protocol_version, "Claim this protocol version in Hello");
  app.add_flag("--disconnect-mid-upload", a.disconnect, "Misbehave: drop the connection halfway through the map");
  app.add_flag("--corrupt-frame", a.corrupt, "Misbehave: send a frame that is not a protobuf message");
  app.add_flag("--oversized-message", a.oversized, "Misbehave: announce a 1 GiB message");
  app.add_flag("--never-read-replies", a.never_read, "Misbehave: never read, flood with Pings");
  app.add_option("--send-recording", a.recording,
                 "Send this recorded session (arref-server --record-dir) instead of mapping a cell");
  app.add_flag("--fast", a.fast, "With --send-recording: as fast as possible instead of the recorded pace");
  app.add_flag("--json", a.json, "Print the outcome as JSON");
  app.add_option("--soak", a.soak_s, "Soak: --clients headsets reconnect and register again and again for this many "
                                     "seconds; prints throughput, latency per session and every error")
      ->check(CLI::Range(0.0, 3600.0));
  app.add_option("--bad-every", a.bad_every, "Soak: every Nth headset misbehaves (cycling through the misbehaviours)")
      ->capture_default_str()->check(CLI::Range(2, 1000));
  app.add_flag("--track", a.track,
               "Continuous referencing instead: stream a simulated track (depth frames, joint states on their own "
               "connection, one world jump) in real time and compare the updates with the truth");
  app.add_option("--track-kind", a.track_options.kind, "--track: long-throw or ahat")
      ->check(CLI::IsMember({"long-throw", "ahat"}))->capture_default_str();
  app.add_option("--track-seconds", a.track_options.duration_s, "--track: stream length")
      ->check(CLI::Range(1.0, 3600.0))->capture_default_str();
  app.add_option("--track-burst", a.track_options.burst, "--track: frames sent at once (to see drops)")
      ->check(CLI::Range(1, 1000))->capture_default_str();
  app.add_option("--track-flying-pixels", a.track_options.flying_pixel_rate,
                 "--track: share of the pixels on depth edges that return a depth between the edge's sides")
      ->check(CLI::Range(0.0, 1.0))->capture_default_str();
  app.add_option("--track-depth-noise", a.track_options.depth_noise_fraction,
                 "--track: depth noise sigma as a fraction of range (0: the frame kind's own, 0.01 long-throw, 0.003 AHAT)")
      ->check(CLI::Range(0.0, 0.2))->capture_default_str();
  app.add_option_function<double>(
         "--track-pose-latency-ms", [&a](double ms) { a.track_options.pose_latency_s = ms / 1000.0; },
         "--track: the camera pose sent is head tracking's this long after the exposure (ms)")
      ->check(CLI::Range(-1000.0, 1000.0));
  app.add_flag("--track-declare-latency", a.track_options.declare_latency,
               "--track: say that latency in the TrackRequest, as a device that knows it");
  app.add_flag("--room", a.room,
               "Map a whole simulated room (built-in robot, --rng-seed) and ask with no seed: the server searches the "
               "whole map (automatic one-shot referencing); prints every instance found and its error")
      ->excludes("--scene", "--seed", "--track", "--send-recording");
  app.add_option("--room-arms", a.room_arms, "--room: arms of the robot in the room (0: the answer must be FAILED)")
      ->check(CLI::Range(0, 2))->capture_default_str();
  app.add_option("--room-mesher", a.room_mesher, "--room: mesher of the room's map")
      ->check(CLI::IsMember({"own", "open3d"}))->capture_default_str();
  app.add_option("--log-level", a.log_level, "trace, debug, info, warn, error")->capture_default_str();
}

Misbehaviour ChosenMisbehaviour(const Args& a) {
  if (a.disconnect) return Misbehaviour::kDisconnectMidUpload;
  if (a.corrupt) return Misbehaviour::kCorruptFrame;
  if (a.oversized) return Misbehaviour::kOversizedMessage;
  if (a.never_read) return Misbehaviour::kNeverReadReplies;
  return Misbehaviour::kNone;
}

Result<HeadsetScene> BuildScene(const Args& a) {
  if (a.room) return SimulatedRoomScene(a.rng_seed, a.room_arms, a.room_mesher);
  if (a.scene.empty()) return SimulatedScene(a.rng_seed);
  ARREF_ASSIGN_OR_RETURN(const FrameConvention frame, ParseFrameConvention(a.frame));
  std::optional<Iso3> seed;
  if (!a.seed.empty()) {
    auto s = ParsePose(a.seed, frame);
    if (!s.ok()) return s.status().WithContext("--seed");
    seed = *s;
  }
  return SceneFromFiles(a.scene, frame, a.truth, seed, a.truth_robot, a.truth_robot_load);
}

nlohmann::json RunJson(const HeadsetRun& run) {
  nlohmann::json j;
  j["ok"] = run.status.ok();
  j["status"] = run.status.ToString();
  j["session_id"] = run.session_id;
  j["server_closed"] = run.server_closed;
  j["got_shutdown"] = run.got_shutdown;
  j["errors"] = nlohmann::json::array();
  for (const auto& e : run.errors)
    j["errors"].push_back({{"code", wire::ErrorCodeName(e.code())}, {"message", e.message()}, {"fatal", e.fatal()},
                           {"request_id", e.request_id()}, {"surface_id", e.surface_id()}});
  j["registrations"] = nlohmann::json::array();
  for (const auto& r : run.registrations) {
    nlohmann::json x{{"request_id", r.request_id}, {"status", wire::pb::ResultStatus_Name(r.result.status())},
                     {"latency_ms", r.latency_ms}, {"rms_m", r.result.rms_m()},
                     {"inlier_fraction", r.result.inlier_fraction()}, {"iterations", r.result.iterations()},
                     {"expected_error_m", r.result.expected_error_m()},
                     {"server_ms", r.result.server_ms()}, {"queue_ms", r.result.queue_ms()},
                     {"message", r.result.message()},
                     {"stages", std::vector<std::string>(r.result.stages().begin(), r.result.stages().end())}};
    const auto& p = r.result.t_world_base();
    x["T_world_base_unity"] = {p.position().x(), p.position().y(), p.position().z(), p.orientation().x(),
                               p.orientation().y(), p.orientation().z(), p.orientation().w()};
    if (r.error)
      x["truth_error"] = {{"add_m", r.error->add_m}, {"translation_m", r.error->translation_m},
                          {"rotation_deg", r.error->rotation_deg}};
    x["primary_candidate"] = r.result.primary_candidate();
    x["candidates"] = nlohmann::json::array();
    for (int i = 0; i < r.result.candidates_size(); ++i) {
      const auto& c = r.result.candidates(i);
      nlohmann::json y{{"status", wire::pb::ResultStatus_Name(c.status())}, {"score", c.score()}, {"margin", c.margin()},
                       {"inlier_fraction", c.inlier_fraction()}, {"expected_error_m", c.expected_error_m()}};
      if (static_cast<std::size_t>(i) < r.candidate_add_m.size()) y["nearest_arm_add_m"] = r.candidate_add_m[static_cast<std::size_t>(i)];
      x["candidates"].push_back(y);
    }
    j["registrations"].push_back(x);
  }
  return j;
}

// A seedless result's instances, the primary marked, each with its error against the room's arms.
void PrintCandidates(const RegistrationOutcome& r) {
  for (int i = 0; i < r.result.candidates_size(); ++i) {
    const auto& c = r.result.candidates(i);
    const auto* m = c.t_world_base_internal().data();
    std::string error;
    if (static_cast<std::size_t>(i) < r.candidate_add_m.size())
      error = fmt::format(", {:.1f} mm from the nearest arm", r.candidate_add_m[static_cast<std::size_t>(i)] * 1e3);
    std::cout << fmt::format("  {} instance {}: {} at ({:.3f}, {:.3f}, {:.3f}) (internal), score {:.3f}, margin {:.3f}, "
                             "expected error {:.1f} mm{}\n", i == r.result.primary_candidate() ? "*" : " ", i,
                             wire::pb::ResultStatus_Name(c.status()), c.t_world_base_internal_size() == 16 ? m[3] : 0.0,
                             c.t_world_base_internal_size() == 16 ? m[7] : 0.0, c.t_world_base_internal_size() == 16 ? m[11] : 0.0,
                             c.score(), c.margin(), c.expected_error_m() * 1e3, error);
  }
}

void PrintHuman(const HeadsetRun& run) {
  for (const auto& e : run.errors)
    std::cout << "server error " << wire::ErrorCodeName(e.code()) << ": " << e.message() << "\n";
  for (const auto& r : run.registrations) {
    const auto& p = r.result.t_world_base();
    std::cout << fmt::format("request {}: {} in {:.0f} ms (server {:.0f} ms, queued {:.0f} ms)\n", r.request_id,
                             wire::pb::ResultStatus_Name(r.result.status()), r.latency_ms, r.result.server_ms(),
                             r.result.queue_ms());
    if (!r.result.message().empty()) std::cout << "  " << r.result.message() << "\n";
    PrintCandidates(r);
    if (r.result.status() != wire::pb::RESULT_STATUS_OK && r.result.status() != wire::pb::RESULT_STATUS_LOW_CONFIDENCE)
      continue;
    std::cout << fmt::format("  T_world_base (Unity): position ({:.4f}, {:.4f}, {:.4f}) rotation ({:.4f}, {:.4f}, {:.4f}, {:.4f})\n",
                             p.position().x(), p.position().y(), p.position().z(), p.orientation().x(),
                             p.orientation().y(), p.orientation().z(), p.orientation().w());
    const auto& m = r.result.t_world_base_internal();
    if (m.size() == 16)
      for (int row = 0; row < 4; ++row)
        std::cout << fmt::format("  {}{:+.5f} {:+.5f} {:+.5f} {:+.5f}\n", row == 0 ? "T_world_base (internal) " : "                        ",
                                 m[4 * row], m[4 * row + 1], m[4 * row + 2], m[4 * row + 3]);
    std::cout << fmt::format("  {}: rms {:.1f} mm ({} model points), inliers {:.1f} %, {} iterations\n",
                             r.result.method(), r.result.rms_m() * 1e3, r.result.rms_points(),
                             r.result.inlier_fraction() * 100, r.result.iterations());
    if (r.result.expected_error_m() > 0)
      std::cout << "  "
                << ExpectedErrorLine(r.result.expected_error_m(), r.result.fit_error_m(), r.result.map_error_m(),
                                     r.result.surface_error_m())
                << "\n";
    if (!r.result.stages().empty())
      std::cout << "  steps: " << fmt::format("{}", fmt::join(r.result.stages(), ", ")) << "\n";
    if (r.error)
      std::cout << fmt::format("  vs truth: ADD {:.1f} mm, translation {:.1f} mm, rotation {:.2f} deg\n",
                               r.error->add_m * 1e3, r.error->translation_m * 1e3, r.error->rotation_deg);
  }
  std::cout << (run.status.ok() ? "OK" : "FAILED: " + run.status.ToString()) << std::endl;
}

void PrintSummary(const std::vector<HeadsetRun>& runs, bool json) {
  const LatencySummary s = SummarizeLatency(runs);
  int ok = 0;
  for (const auto& r : runs) ok += r.status.ok();
  if (json) {
    nlohmann::json j{{"clients", runs.size()}, {"clients_ok", ok}, {"results", s.count},
                     {"latency_median_ms", s.median_ms}, {"latency_p95_ms", s.p95_ms}, {"latency_max_ms", s.max_ms}};
    j["runs"] = nlohmann::json::array();
    for (const auto& r : runs) j["runs"].push_back(RunJson(r));
    std::cout << j.dump(2) << std::endl;
    return;
  }
  for (const auto& r : runs)
    if (!r.status.ok()) std::cout << "headset failed: " << r.status.ToString() << "\n";
  std::cout << fmt::format("{} of {} headsets OK; {} results; latency (request sent -> result) median {:.0f} ms, "
                           "p95 {:.0f} ms, max {:.0f} ms\n", ok, runs.size(), s.count, s.median_ms, s.p95_ms, s.max_ms);
}

// ---------------------------------------------------------------- soak

struct SoakHeadset {
  bool bad = false;
  int sessions = 0, failed_sessions = 0;
  std::vector<double> latency_ms;
  std::map<std::string, int> errors;  // by code (and, for failed good sessions, by status)
  std::vector<std::string> failures;  // the first few failed good sessions' statuses
};

// Headset i loops until the deadline: a good one maps, registers three times and leaves; a bad
// one (every bad_every-th) misbehaves, each time in the next way.
void SoakLoop(const HeadsetScene& scene, HeadsetOptions options, int i, int bad_every, Clock::time_point deadline,
              SoakHeadset* out) {
  static const Misbehaviour kBad[] = {Misbehaviour::kCorruptFrame, Misbehaviour::kOversizedMessage,
                                      Misbehaviour::kDisconnectMidUpload, Misbehaviour::kNeverReadReplies};
  out->bad = i % bad_every == bad_every - 1;
  options.client_name += "-" + std::to_string(i);
  options.seed_index = i;
  options.repeat = out->bad ? 1 : 3;
  for (int round = 0; Clock::now() < deadline; ++round) {
    options.misbehaviour = out->bad ? kBad[(i / bad_every + round) % std::size(kBad)] : Misbehaviour::kNone;
    options.first_request_id = 1;
    const HeadsetRun run = RunHeadset(scene, options);
    ++out->sessions;
    for (const auto& e : run.errors) ++out->errors[wire::ErrorCodeName(e.code())];
    for (const auto& r : run.registrations)
      if (r.result.status() == pb::RESULT_STATUS_OK || r.result.status() == pb::RESULT_STATUS_LOW_CONFIDENCE)
        out->latency_ms.push_back(r.latency_ms);
    if (!out->bad && !run.status.ok()) {
      ++out->failed_sessions;
      ++out->errors["good session failed: " + std::string(StatusCodeName(run.status.code()))];
      if (out->failures.size() < 3) out->failures.push_back(run.status.ToString());
    }
  }
}

int RunSoak(const HeadsetScene& scene, const Args& a) {
  const auto start = Clock::now();
  const auto deadline = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(a.soak_s));
  std::vector<SoakHeadset> headsets(static_cast<std::size_t>(a.clients));
  std::vector<std::thread> threads;
  for (int i = 0; i < a.clients; ++i)
    threads.emplace_back(SoakLoop, std::cref(scene), a.options, i, a.bad_every, deadline, &headsets[i]);
  for (auto& t : threads) t.join();
  const double wall_s = std::chrono::duration<double>(Clock::now() - start).count();
  std::vector<double> all, per_session_median, per_session_p95;
  std::map<std::string, int> errors;
  int good = 0, bad = 0, sessions = 0, failed = 0;
  for (const auto& h : headsets) {
    (h.bad ? bad : good)++;
    sessions += h.sessions;
    failed += h.failed_sessions;
    all.insert(all.end(), h.latency_ms.begin(), h.latency_ms.end());
    if (!h.bad && !h.latency_ms.empty()) {
      per_session_median.push_back(Quantile(h.latency_ms, 0.5));
      per_session_p95.push_back(Quantile(h.latency_ms, 0.95));
    }
    for (const auto& [code, n] : h.errors) errors[code] += n;
  }
  std::cout << fmt::format("soak: {} headsets ({} good, {} misbehaving) for {:.0f} s: {} sessions, {} results, "
                           "{:.2f} results/s\n", a.clients, good, bad, wall_s, sessions, all.size(),
                           static_cast<double>(all.size()) / wall_s);
  std::cout << fmt::format("latency (request sent -> result): median {:.0f} ms, p95 {:.0f} ms, max {:.0f} ms\n",
                           Quantile(all, 0.5), Quantile(all, 0.95), Quantile(all, 1.0));
  std::cout << fmt::format("per good headset: median latency {:.0f} .. {:.0f} ms (min .. max over headsets), p95 "
                           "{:.0f} .. {:.0f} ms\n", Quantile(per_session_median, 0), Quantile(per_session_median, 1),
                           Quantile(per_session_p95, 0), Quantile(per_session_p95, 1));
  std::cout << fmt::format("good sessions failed: {}\n", failed);
  std::size_t shown = 0;  // the first few are enough; the counts by code follow
  for (const auto& h : headsets)
    for (const auto& f : h.failures)
      if (shown++ < 5) std::cout << "  " << f << "\n";
  std::cout << "errors the server sent (and failed good sessions), by code:\n";
  for (const auto& [code, n] : errors) std::cout << fmt::format("  {:>6}  {}\n", n, code);
  return failed == 0 ? 0 : 1;
}

// Median and 95th percentile of a list (stats.h's quantiles, as every table's); 0 when empty.
std::pair<double, double> MedianP95(const std::vector<double>& v) {
  if (v.empty()) return {0.0, 0.0};
  return {Quantile(v, 0.5), Quantile(v, 0.95)};
}

int RunTrack(Args& args) {
  TrackHeadsetOptions& o = args.track_options;
  o.host = args.options.host, o.port = args.options.port, o.robot_id = args.options.robot_id, o.rng_seed = args.rng_seed;
  o.tls = args.options.tls;
  const TrackHeadsetRun run = RunTrackingHeadset(o);
  if (!run.status.ok()) {
    std::cout << "FAILED: " << run.status.ToString() << std::endl;
    return 1;
  }
  for (const auto& e : run.errors) std::cout << "server error " << wire::ErrorCodeName(e.code()) << ": " << e.message() << "\n";
  std::vector<double> add, client_ms, server_ms, process_ms;
  int scored = 0, within = 0;
  const std::vector<bool> settled = SettledUpdates(run);
  for (std::size_t i = 0; i < run.updates.size(); ++i) {
    const TrackUpdateRecord& u = run.updates[i];
    client_ms.push_back(u.latency_ms), server_ms.push_back(u.server_latency_ms), process_ms.push_back(u.process_ms);
    if (!settled[i]) continue;
    ++scored, within += u.add_mm < 10;
    add.push_back(u.add_mm);
  }
  const auto [add_med, add_p95] = MedianP95(add);
  const auto [c_med, c_p95] = MedianP95(client_ms);
  const auto [s_med, s_p95] = MedianP95(server_ms);
  const auto [p_med, p_p95] = MedianP95(process_ms);
  std::cout << fmt::format(
      "{} frames sent, {} updates, {} dropped; {} of {} steady updates within ADD 10 mm (median {:.1f}, p95 {:.1f} mm); "
      "latency frame sent -> update read median {:.1f} ms p95 {:.1f}; server frame received -> update sent median "
      "{:.1f} p95 {:.1f}; processing median {:.1f} p95 {:.1f}; clock offset error {:.2f} ms; subscriber got {}; "
      "depth noise the server measured {:.2f} % of range\n",
      run.frames_sent, run.updates.size(), run.frames_dropped, within, scored, add_med, add_p95, c_med, c_p95, s_med,
      s_p95, p_med, p_p95, 1000 * run.reported_offset_error_s, run.subscriber_updates,
      run.updates.empty() ? 0.0 : 100 * run.updates.back().depth_noise);
  if (scored == 0) {
    std::cout << "FAILED: no settled update to score (a second of processed frames after the start and after the "
                 "jump): the server dropped too many frames, or the stream is too short\n";
    return 1;
  }
  return within >= 0.95 * scored ? 0 : 1;
}

// A room without the arm: the right answer is FAILED with no instance, in every run.
bool RoomWithoutArmFailed(const std::vector<HeadsetRun>& runs) {
  for (const auto& run : runs) {
    if (run.registrations.empty()) return false;  // refused or cut off: no answer at all
    for (const auto& r : run.registrations)
      if (r.result.status() != wire::pb::RESULT_STATUS_FAILED || r.result.candidates_size() > 0) return false;
  }
  std::cout << "room without the arm: FAILED with no instance, as it should\n";
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"arref-mock-headset: behaves like the HoloLens app against arref-server"};
  Args args;
  AddFlags(app, args);
  CLI11_PARSE(app, argc, argv);
  spdlog::set_default_logger(spdlog::stderr_color_mt("mock-headset"));
  spdlog::set_level(spdlog::level::from_str(args.log_level));
  args.options.port = static_cast<std::uint16_t>(args.port);
  args.options.misbehaviour = ChosenMisbehaviour(args);
  const TlsClientOptions& tls = args.options.tls;
  if (!tls.ca_file.empty() || !tls.server_name.empty() || !tls.certificate.empty())
    args.options.tls.enabled = true;  // any TLS option means TLS
  if (args.track) return RunTrack(args);
  if (args.clients == 1 && args.options.repeat == 1 && !args.json)
    args.options.on_progress = [](const wire::pb::Progress& p) {
      std::cerr << fmt::format("request {}: {} {:.0f} %\n", p.request_id(), p.stage(), p.fraction() * 100);
    };
  if (!args.recording.empty()) {
    auto recording = wire::ReadRecording(args.recording);
    if (!recording.ok()) {
      spdlog::error("{}", recording.status().ToString());
      return 3;
    }
    const HeadsetRun run = SendRecording(*recording, args.options, args.fast ? Pace::kFast : Pace::kOriginal);
    if (args.json)
      std::cout << RunJson(run).dump(2) << std::endl;
    else
      PrintHuman(run);
    return run.status.ok() ? 0 : 1;
  }
  auto scene = BuildScene(args);
  if (!scene.ok()) {
    spdlog::error("{}", scene.status().ToString());
    return 3;
  }
  if (args.soak_s > 0) return RunSoak(*scene, args);
  if (args.room && !args.json) {
    std::size_t triangles = 0;
    for (const Surface& s : scene->surfaces) triangles += s.mesh.triangles.size();
    std::cout << fmt::format("room {}: {} arms, {} triangles in {} surfaces ({} mesher), no seed\n", args.rng_seed,
                             args.room_arms, triangles, scene->surfaces.size(), args.room_mesher);
  }
  std::vector<HeadsetRun> runs;
  if (args.clients > 1 || args.options.repeat > 1) {  // latency figures
    runs = RunHeadsets(*scene, args.options, args.clients);
    PrintSummary(runs, args.json);
  } else {
    runs.push_back(RunHeadset(*scene, args.options));
    if (args.json)
      std::cout << RunJson(runs[0]).dump(2) << std::endl;
    else
      PrintHuman(runs[0]);
  }
  if (args.room && args.room_arms == 0) return RoomWithoutArmFailed(runs) ? 0 : 1;
  for (const auto& r : runs)
    if (!r.status.ok()) return 1;
  return 0;
}
