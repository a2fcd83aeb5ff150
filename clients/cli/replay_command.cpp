// `arref replay FILE`: a session recorded by arref-server (--record-dir) re-run offline with the
// server's own request handling, printing what the server answered (or would have) to each message.
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <iostream>
#include <map>
#include <nlohmann/json.hpp>

#include "cli_common.h"
#include "commands.h"
#include "convert.h"
#include "recording.h"
#include "replay.h"
#include "server_config.h"

namespace arref::cli {
namespace {

namespace pb = wire::pb;

struct ReplayArgs {
  std::string file;
  std::string config;  // empty: the built-in server config (for the robots)
  bool config_registration = false;
  bool json = false;
};

const char* FrameName(pb::FrameConvention f) { return f == pb::FRAME_CONVENTION_UNITY ? "unity" : "ros"; }

nlohmann::json AnswerJson(const server::ReplayedAnswer& a) {
  nlohmann::json j{{"t_s", a.t_s}, {"message_index", a.message_index}};
  if (a.message.has_error()) {
    const auto& e = a.message.error();
    j["error"] = wire::ErrorCodeName(e.code());
    j["message"] = e.message();
    j["request_id"] = e.request_id();
    j["surface_id"] = e.surface_id();
    return j;
  }
  if (a.message.has_pong()) {
    j["pong"] = a.message.pong().nonce();
    j["server_time_s"] = a.message.pong().server_time_s();
    return j;
  }
  if (a.message.has_tracking_update()) {
    const pb::TrackingUpdate& u = a.message.tracking_update();
    const auto& p = u.t_world_base();
    j["tracking_update"] = u.frame_id();
    j["robot_id"] = u.robot_id();
    j["state"] = u.state();
    j["frame"] = FrameName(u.frame());
    j["frame_time_s"] = u.frame_time_s();
    j["frame_time_unix_s"] = u.frame_time_unix_s();
    j["position"] = {p.position().x(), p.position().y(), p.position().z()};
    j["orientation"] = {p.orientation().x(), p.orientation().y(), p.orientation().z(), p.orientation().w()};
    j["agreement"] = u.agreement();
    j["joint_staleness_s"] = u.joint_staleness_s();
    j["process_ms"] = u.process_ms();
    return j;
  }
  if (a.message.has_subscribed()) {
    j["subscribed"] = a.message.subscribed().robot_id();
    j["subscribing"] = a.message.subscribed().subscribed();
    return j;
  }
  const pb::Result& r = a.message.result();
  const auto& p = r.t_world_base();
  j["request_id"] = r.request_id();
  j["status"] = pb::ResultStatus_Name(r.status()).substr(std::string("RESULT_STATUS_").size());
  j["robot_id"] = r.robot_id();
  j["frame"] = FrameName(r.frame());
  j["position"] = {p.position().x(), p.position().y(), p.position().z()};
  j["orientation"] = {p.orientation().x(), p.orientation().y(), p.orientation().z(), p.orientation().w()};
  j["T_world_base"] = std::vector<double>(r.t_world_base_internal().begin(), r.t_world_base_internal().end());
  j["rms_m"] = r.rms_m();
  j["inlier_fraction"] = r.inlier_fraction();
  j["iterations"] = r.iterations();
  j["method"] = r.method();
  j["message"] = r.message();
  j["stages"] = std::vector<std::string>(r.stages().begin(), r.stages().end());
  return j;
}

void PrintHuman(const nlohmann::json& j) {
  if (j.contains("error")) {
    std::cout << fmt::format("t={:.3f} s: error {}: {}\n", j["t_s"].get<double>(), j["error"].get<std::string>(),
                             j["message"].get<std::string>());
    return;
  }
  if (j.contains("pong")) {
    std::cout << fmt::format("t={:.3f} s: pong {}\n", j["t_s"].get<double>(), j["pong"].get<std::uint64_t>());
    return;
  }
  if (j.contains("tracking_update")) {
    const auto& p = j["position"];
    std::cout << fmt::format("t={:.3f} s: frame {} of {}: {} at ({:+.4f}, {:+.4f}, {:+.4f}) {}, agreement {:.2f}\n",
                             j["t_s"].get<double>(), j["tracking_update"].get<std::uint64_t>(),
                             j["robot_id"].get<std::string>(), j["state"].get<std::string>(), p[0].get<double>(),
                             p[1].get<double>(), p[2].get<double>(), j["frame"].get<std::string>(),
                             j["agreement"].get<double>());
    return;
  }
  if (j.contains("subscribed")) {
    std::cout << fmt::format("t={:.3f} s: {} {}\n", j["t_s"].get<double>(),
                             j["subscribing"].get<bool>() ? "subscribed to" : "unsubscribed from",
                             j["subscribed"].get<std::string>());
    return;
  }
  std::cout << fmt::format("t={:.3f} s: request {} on {}: {}{}\n", j["t_s"].get<double>(),
                           j["request_id"].get<std::uint64_t>(), j["robot_id"].get<std::string>(),
                           j["status"].get<std::string>(),
                           j["message"].get<std::string>().empty() ? "" : " (" + j["message"].get<std::string>() + ")");
  const auto& T = j["T_world_base"];
  if (T.size() == 16)
    for (int r = 0; r < 4; ++r)
      std::cout << fmt::format("  {}{:+.5f} {:+.5f} {:+.5f} {:+.5f}\n", r == 0 ? "T_world_base (internal) " : "                        ",
                               T[4 * r].get<double>(), T[4 * r + 1].get<double>(), T[4 * r + 2].get<double>(),
                               T[4 * r + 3].get<double>());
  std::cout << fmt::format("  {}: rms {:.1f} mm, inliers {:.1f} %, {} iterations\n", j["method"].get<std::string>(),
                           j["rms_m"].get<double>() * 1e3, j["inlier_fraction"].get<double>() * 100,
                           j["iterations"].get<int>());
}

int Run(const ReplayArgs& args) {
  auto recording = wire::ReadRecording(args.file);
  if (!recording.ok()) return Fail(recording.status());
  const auto& h = recording->header;
  spdlog::info("replay: {} messages of session {} ('{}') recorded by arref-server {}", recording->messages.size(),
               h.session_id(), h.client_name(), h.server_version());
  auto config = args.config.empty() ? server::LoadDefaultServerConfig() : server::LoadServerConfig(args.config);
  if (!config.ok()) return Fail(config.status().WithContext("--config"));
  bool none_failed = true;
  std::map<std::string, int> tracking_states;
  const auto print = [&](const server::ReplayedAnswer& a) {
    const nlohmann::json j = AnswerJson(a);
    if (a.message.has_tracking_update()) ++tracking_states[a.message.tracking_update().state()];
    // A request the client cancelled is what it asked for, not a failure.
    if (a.message.has_result()) none_failed &= a.message.result().status() != pb::RESULT_STATUS_FAILED;
    if (args.json)
      std::cout << j.dump() << std::endl;
    else
      PrintHuman(j);
  };
  auto answers = server::ReplayRecording(*recording, *config,
                                         server::ReplayOptions{.recorded_registration = !args.config_registration}, print);
  if (!answers.ok()) return Fail(answers.status());
  if (!tracking_states.empty()) {
    std::string counts;
    for (const auto& [state, n] : tracking_states) counts += fmt::format("{}{} {}", counts.empty() ? "" : ", ", n, state);
    spdlog::info("replay: tracking updates: {}", counts);
  }
  return none_failed ? kExitOk : kExitRegistrationFailed;
}

}  // namespace

void AddReplayCommand(CLI::App& app, int* exit_code) {
  auto args = std::make_shared<ReplayArgs>();
  CLI::App* cmd = app.add_subcommand("replay", "Re-run a session recorded by arref-server offline (registrations and tracking) and print each answer");
  cmd->add_option("file", args->file, "Recording (arref-server --record-dir DIR writes DIR/arref-session-*.arrec)")
      ->required();
  cmd->add_option("--config", args->config,
                  "Server config whose robots the recording's robot ids name (default: the built-in config)");
  cmd->add_flag("--config-registration", args->config_registration,
                "Register with --config's registration settings instead of the recorded server's");
  cmd->add_flag("--json", args->json, "One JSON object per answer (Result, TrackingUpdate, Error, Pong, Subscribed) on stdout");
  cmd->callback([args, exit_code] { *exit_code = Run(*args); });
}

}  // namespace arref::cli
