#include "track_client.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <map>
#include <thread>

#include "arref/base/builtin.h"
#include "arref/scene/metrics.h"
#include "arref/scene/sampling.h"
#include "arref/sim/track_simulator.h"
#include "arref/track/clock_sync.h"
#include "convert.h"

namespace arref::headset {
namespace {

using Clock = std::chrono::steady_clock;
double MachineNow() { return std::chrono::duration<double>(Clock::now().time_since_epoch()).count(); }
// A time on the machine's steady clock as Unix time.
double UnixTimeOf(double machine_time_s) {
  const double unix_now =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  return unix_now - (MachineNow() - machine_time_s);
}

// A connection whose sender keeps its own clock (the machine's plus an offset).
struct Peer {
  Connection conn;
  double clock_offset_s = 0.0;
  ClockOffsetEstimator estimator;
  std::uint64_t session_id = 0;
  double Now() const { return MachineNow() + clock_offset_s; }
};

Status Hello(Peer& p, const TrackHeadsetOptions& o, const std::string& name) {
  ARREF_ASSIGN_OR_RETURN(p.conn, Connection::Connect(o.host, o.port, o.timeout_s, 0, o.tls));
  pb::ClientMessage m;
  m.mutable_hello()->set_protocol_version(wire::kProtocolVersion);
  m.mutable_hello()->set_client_name(name);
  ARREF_RETURN_IF_ERROR(p.conn.Send(m));
  ARREF_ASSIGN_OR_RETURN(const pb::ServerMessage reply, p.conn.Receive(o.timeout_s));
  if (!reply.has_hello_reply()) return Status::Internal(name + ": expected HelloReply");
  p.session_id = reply.hello_reply().session_id();
  return Status::Ok();
}

// A few NTP-like exchanges, then the best estimate reported to the server.
Status SyncClock(Peer& p, const TrackHeadsetOptions& o, int exchanges) {
  for (int i = 0; i < exchanges; ++i) {
    pb::ClientMessage m;
    m.mutable_ping()->set_nonce(static_cast<std::uint64_t>(i) + 1000);
    m.mutable_ping()->set_client_time_s(p.Now());
    ARREF_RETURN_IF_ERROR(p.conn.Send(m));
    for (;;) {
      ARREF_ASSIGN_OR_RETURN(const pb::ServerMessage reply, p.conn.Receive(o.timeout_s));
      if (!reply.has_pong()) continue;  // updates may arrive meanwhile; the caller reads them later
      const double t3 = p.Now();
      const pb::Pong& pong = reply.pong();
      ARREF_RETURN_IF_ERROR(p.estimator.Add({pong.client_time_s(), pong.receive_time_s(), pong.server_time_s(), t3}));
      break;
    }
  }
  pb::ClientMessage report;
  report.mutable_clock_report()->set_offset_s(p.estimator.offset_s());
  report.mutable_clock_report()->set_uncertainty_s(p.estimator.uncertainty_s());
  return p.conn.Send(report);
}

}  // namespace

TrackHeadsetRun RunTrackingHeadset(const TrackHeadsetOptions& o) {
  TrackHeadsetRun out;
  auto fail = [&](Status s) {
    out.status = std::move(s);
    return out;
  };
  auto urdf = BuiltinRobotUrdf();
  if (!urdf.ok()) return fail(urdf.status());
  auto loaded = RobotModel::Load(*urdf);
  if (!loaded.ok()) return fail(loaded.status());
  auto robot = std::make_shared<const RobotModel>(std::move(*loaded));
  auto kind = sim::ParseFrameKind(o.kind);
  if (!kind.ok()) return fail(kind.status());
  sim::TrackSimOptions so;
  so.kind = *kind;
  so.duration_s = o.duration_s;
  so.jump_at_s = o.jump_at_s;
  so.sender_clock_offset_s = 0.0;  // the peers' clocks below carry the offsets
  so.flying_pixel_rate = o.flying_pixel_rate;
  so.pose_latency_s = o.pose_latency_s;
  so.depth_noise_fraction = o.depth_noise_fraction;
  auto simulator = sim::TrackSimulator::Create(robot, so, o.rng_seed);
  if (!simulator.ok()) return fail(simulator.status());
  out.jump_time_s = simulator->jump_time_s();
  out.frames_per_s = simulator->frame_count() / so.duration_s;
  const std::vector<Vec3f> add_points = SampleSurface(*robot->PosedMesh({}), 2000, 1).points;

  Peer headset, sender, watcher;
  headset.clock_offset_s = o.headset_clock_offset_s;
  sender.clock_offset_s = o.sender_clock_offset_s;
  if (auto st = Hello(headset, o, "arref-track-headset"); !st.ok()) return fail(st);
  if (auto st = Hello(sender, o, "arref-robot-joints"); !st.ok()) return fail(st);
  if (auto st = SyncClock(headset, o, 8); !st.ok()) return fail(st.WithContext("headset clock"));
  if (auto st = SyncClock(sender, o, 8); !st.ok()) return fail(st.WithContext("sender clock"));
  // The server's clock is this machine's steady clock: the truth of the headset's offset.
  out.reported_offset_error_s = headset.estimator.offset_s() + o.headset_clock_offset_s;
  if (o.subscriber) {
    if (auto st = Hello(watcher, o, "arref-cell-watcher"); !st.ok()) return fail(st);
    pb::ClientMessage sub;
    sub.mutable_subscribe()->set_robot_id(o.robot_id);
    if (auto st = watcher.conn.Send(sub); !st.ok()) return fail(st);
  }
  {
    // A seed as a one-shot registration leaves it: a few centimetres and degrees off.
    pb::ClientMessage m;
    m.mutable_track_request()->set_robot_id(o.robot_id);
    m.mutable_track_request()->set_result_frame(pb::FRAME_CONVENTION_ROS);
    if (o.declare_latency) m.mutable_track_request()->set_camera_pose_latency_s(o.pose_latency_s);
    *m.mutable_track_request()->mutable_seed()->mutable_t_world_seed() = wire::PoseToProto(
        simulator->T_world_base_initial() * MakeYawPose(0.03, -0.02, 0.01, 0.05), FrameConvention::kRos);
    m.mutable_track_request()->mutable_seed()->set_frame(pb::FRAME_CONVENTION_ROS);
    if (auto st = headset.conn.Send(m); !st.ok()) return fail(st);
  }

  double start = 0.0;  // the stream's true time 0 on the machine's steady clock
  struct Sent { double true_time_s; bool after_jump; Iso3 truth; Clock::time_point at; };
  std::map<std::uint64_t, Sent> sent;
  auto read_updates = [&](double timeout_s) -> Status {
    for (;;) {
      auto reply = headset.conn.Receive(timeout_s);
      if (!reply.ok()) return reply.status().code() == StatusCode::kResourceExhausted ? Status::Ok() : reply.status();
      timeout_s = 0.0005;
      if (reply->has_error()) {
        out.errors.push_back(reply->error());
        continue;
      }
      if (!reply->has_tracking_update()) continue;
      const pb::TrackingUpdate& u = reply->tracking_update();
      auto it = sent.find(u.frame_id());
      if (it == sent.end()) continue;
      auto T = wire::PoseFromProto(u.t_world_base(), FrameConvention::kRos);
      if (!T.ok()) return T.status();
      TrackUpdateRecord r;
      r.frame_id = u.frame_id();
      r.state = u.state();
      r.add_mm = 1000 * ComparePoses(*T, it->second.truth, add_points).add_m;
      r.latency_ms = std::chrono::duration<double, std::milli>(Clock::now() - it->second.at).count();
      r.server_latency_ms = u.latency_ms();
      r.process_ms = u.process_ms();
      r.true_time_s = it->second.true_time_s;
      r.after_jump = it->second.after_jump;
      r.unix_time_error_s = u.frame_time_unix_s() - UnixTimeOf(start + it->second.true_time_s);
      r.depth_noise = u.depth_noise();
      out.frames_dropped = u.frames_dropped();
      out.updates.push_back(r);
    }
  };

  start = MachineNow();
  double last_joint_time = -1.0;
  struct Ready { pb::ClientMessage message; std::uint64_t id; Sent sent; };
  std::vector<Ready> burst;  // made before any is sent, so that they arrive together
  for (int i = 0; i < simulator->frame_count(); ++i) {
    auto f = simulator->Next();
    if (!f.ok()) return fail(f.status());
    for (const auto& js : simulator->JointSamples(last_joint_time, f->true_time_s)) {
      pb::ClientMessage m;
      pb::JointState* j = m.mutable_joint_state();
      j->set_robot_id(o.robot_id);
      j->set_timestamp_s(start + js.sender_time_s + o.sender_clock_offset_s);
      for (const auto& [name, value] : js.joints) j->add_names(name), j->add_positions(value);
      if (auto st = sender.conn.Send(m); !st.ok()) return fail(st.WithContext("joint sender"));
    }
    last_joint_time = f->true_time_s;
    sim::SimFrame& frame = *f;
    frame.frame.time_s = start + frame.true_time_s + o.headset_clock_offset_s;
    Ready r;
    *r.message.mutable_depth_frame() = wire::DepthFrameToProto(frame.frame, FrameConvention::kRos);
    r.id = static_cast<std::uint64_t>(i) + 1;
    r.message.mutable_depth_frame()->set_robot_id(o.robot_id);
    r.message.mutable_depth_frame()->set_frame_id(r.id);
    r.sent = {frame.true_time_s, frame.after_jump, frame.T_world_base_true, Clock::now()};
    burst.push_back(std::move(r));
    if (static_cast<int>(burst.size()) < o.burst && i + 1 < simulator->frame_count()) continue;
    // Real time: a frame leaves when its exposure has come (a burst: its newest frame's).
    while (MachineNow() < start + burst.back().sent.true_time_s) std::this_thread::sleep_for(std::chrono::microseconds(500));
    for (Ready& b : burst) {
      b.sent.at = Clock::now();
      sent[b.id] = b.sent;
      if (auto st = headset.conn.Send(b.message); !st.ok()) return fail(st.WithContext("depth frame"));
      ++out.frames_sent;
    }
    burst.clear();
    if (auto st = read_updates(0.0005); !st.ok()) return fail(st);
  }
  // The last frames' updates, then the subscriber's count.
  const auto deadline = Clock::now() + std::chrono::duration<double>(5.0);
  while (Clock::now() < deadline &&
         static_cast<std::uint64_t>(out.updates.size()) + out.frames_dropped < static_cast<std::uint64_t>(out.frames_sent))
    if (auto st = read_updates(0.05); !st.ok()) return fail(st);
  if (o.subscriber)
    for (;;) {
      auto reply = watcher.conn.Receive(0.2);
      if (!reply.ok()) break;
      if (reply->has_tracking_update()) ++out.subscriber_updates;
    }
  out.status = Status::Ok();
  return out;
}

std::vector<bool> SettledUpdates(const TrackHeadsetRun& run) {
  const int second_of_frames = static_cast<int>(std::lround(run.frames_per_s));
  std::vector<bool> settled(run.updates.size(), false);
  int since_start = 0, since_jump = 0;
  for (std::size_t i = 0; i < run.updates.size(); ++i) {
    const TrackUpdateRecord& u = run.updates[i];
    ++since_start;
    if (u.after_jump) ++since_jump;
    const bool warm = u.true_time_s >= 1.0 && since_start > second_of_frames;
    const bool recovered = !u.after_jump || (u.true_time_s >= run.jump_time_s + 1.0 && since_jump > second_of_frames);
    settled[i] = warm && recovered;
  }
  return settled;
}

}  // namespace arref::headset
