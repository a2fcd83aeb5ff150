// One headset connection (internal to the server; includes Asio and the protocol).
//
// Everything a session owns is touched only on its strand: reads are chained one after the
// other, writes go through a bounded queue, timers and posts from worker threads land on the
// same strand. A session closes itself on a fatal error; it never throws past its handlers.
#pragma once

// Boost 1.74 Asio uses std::exchange without including <utility> in C++20 mode.
#include <utility>

#include <boost/asio.hpp>

#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "arref/scene/spatial_mesh.h"
#include "arref/base/clock.h"
#include "frame_decoder.h"
#include "job_scheduler.h"
#include "mapping_motion.h"
#include "memory_budget.h"
#include "recording.h"
#include "request_builder.h"
#include "robot_registry.h"
#include "server_config.h"
#include "subscriber_hub.h"
#include "tracking_service.h"
#include "transport.h"
#include "wire.h"

namespace arref::server {

// What every session shares: set up once by the server.
struct ServerContext {
  const ServerConfig& config;
  RobotRegistry& robots;
  JobScheduler& jobs;
  SubscriberHub& hub;
  TrackingService& tracking;
  std::atomic<bool>& shutting_down;
  MemoryBudget& memory;
  // A connection that completed Hello asks to become a session (limits.max_sessions); an error
  // refuses it. Called on the session's strand.
  std::function<Status(std::uint64_t session_id)> on_hello;
  std::function<void(std::uint64_t session_id)> on_session_closed;
  std::string server_version;
  TlsContext* tls;  // nullptr: plain TCP
};

// The largest frame accepted before Hello (Hello itself is a few hundred bytes), so that
// connections that have not identified themselves cannot make the server buffer much.
constexpr std::size_t kMaxHelloBytes = 64 * 1024;
// Frames from this size on are charged to the memory budget while they are received.
constexpr std::size_t kChargedFrameBytes = 64 * 1024;
constexpr std::size_t kMaxPingPayload = 64 * 1024;

class Session : public TrackingSink, public std::enable_shared_from_this<Session> {
 public:
  // Over a TCP connection (plain or TLS, as the context says).
  Session(tcp::socket socket, ServerContext& context, std::uint64_t id);
  // Over any transport (the fuzz harness feeds bytes from memory).
  Session(std::unique_ptr<Transport> transport, ServerContext& context, std::uint64_t id);
  ~Session();

  std::uint64_t id() const override { return id_; }
  void Start();
  // Rejects the connection with a fatal error (e.g. too many sessions).
  void Reject(wire::pb::ErrorCode code, const std::string& message);

  // Thread-safe: these post onto the session's strand.
  void SendFrame(std::shared_ptr<const std::string> frame) override;
  void DeliverResult(std::uint64_t request_id, std::shared_ptr<const std::string> frame);
  void NotifyShutdown(double grace_s);
  void CloseGracefully(const std::string& reason);

 private:
  enum class State { kAwaitHello, kReady, kClosing, kClosed };

  // TLS: the handshake runs before the first read, under the Hello deadline.
  void StartTls();
  void OnTlsHandshake(const boost::system::error_code& ec);

  // Reading and framing.
  void ReadMore();
  void OnRead(const boost::system::error_code& ec, std::size_t bytes);
  void OnReadEnd(const boost::system::error_code& ec);
  bool ProcessFrames();  // false when the session started closing
  bool ChargeNextFrame();  // reserves a large frame's memory, or skips it; false: skipped
  void ArmIdleTimer();
  void ArmHelloTimer();
  void UpdateFrameTimer(bool frame_completed);

  // Message handlers.
  void Handle(const wire::pb::ClientMessage& message);
  void OnHello(const wire::pb::Hello& m);
  void OnSurfaceUpsert(const wire::pb::SurfaceUpsert& m);
  // The session's limits and the memory budget for a surface of this size replacing `sid`.
  Result<MemoryBudget::Reservation> AdmitSurface(std::uint64_t sid, std::size_t vertices, std::size_t triangles);
  void FillHelloReply(wire::pb::HelloReply* r) const;
  void OnSurfaceRemove(const wire::pb::SurfaceRemove& m);
  void OnSeedPose(const wire::pb::SeedPose& m);
  void OnJointState(const wire::pb::JointState& m);
  void OnRegisterRequest(const wire::pb::RegisterRequest& m);
  void OnCancel(const wire::pb::Cancel& m);
  void OnSubscribe(const wire::pb::Subscribe& m);
  void OnPing(const wire::pb::Ping& m);
  void OnDepthFrame(const wire::pb::DepthFrame& m);
  void OnTrackRequest(const wire::pb::TrackRequest& m);
  void OnClockReport(const wire::pb::ClockReport& m);

  // A job for the request (request_builder.h) with this session's scene and callbacks; an
  // error is sent and nullptr returned on bad input.
  std::shared_ptr<Job> MakeJob(const wire::pb::RegisterRequest& m);
  void AttachCallbacks(Job& job);

  // Recording (config record_dir): opened once Hello is accepted; a failure stops only the
  // recording, never the session.
  void StartRecording(const wire::pb::HelloReply& reply, const wire::pb::ClientMessage& hello);
  void Record(const wire::pb::ClientMessage& message);
  void RecordAnswer(std::uint64_t request_id);  // a Result sent (so replays decide Cancels as live)
  void KeepRecording(const Status& written);

  // Writing.
  void Send(const wire::pb::ServerMessage& message);
  void SendError(wire::pb::ErrorCode code, const std::string& message, std::uint64_t request_id = 0,
                 std::uint64_t surface_id = 0);
  void Enqueue(std::shared_ptr<const std::string> frame);
  void WriteNext();
  void OnWrite(const boost::system::error_code& ec, std::size_t bytes);

  // Closing.
  void FailAndClose(wire::pb::ErrorCode code, const std::string& message);  // fatal error, then flush + close
  void StartClosing(const std::string& reason);
  void FinishClosing();                       // after StartClosing, once every reply is written
  void CloseNow(const std::string& reason);  // drops unsent data

  std::unique_ptr<Transport> transport_;
  ServerContext& ctx_;
  const std::uint64_t id_;
  State state_ = State::kAwaitHello;
  // TLS not yet established (a refused connection never starts it): nothing can be sent, not
  // even an Error, so a fatal error just closes.
  bool handshaking_;
  std::string peer_;
  std::string client_name_;
  std::string close_reason_;

  wire::FrameDecoder rx_;
  net::steady_timer idle_timer_;
  net::steady_timer hello_timer_;
  net::steady_timer frame_timer_;
  bool frame_timer_armed_ = false;
  MemoryBudget::Reservation frame_memory_;  // the large frame being received
  bool read_closed_ = false;                // the client half-closed: deliver results, then close
  bool reading_ = false;                    // a read is pending on the transport
  bool finishing_ = false;                  // FinishClosing called: every reply written
  bool transport_closing_ = false;          // the transport's graceful close has begun
  net::steady_timer write_timer_;
  net::steady_timer linger_timer_;

  std::deque<std::shared_ptr<const std::string>> write_queue_;
  std::size_t write_queue_bytes_ = 0;
  bool writing_ = false;

  SpatialMesh spatial_;
  std::map<std::uint64_t, MemoryBudget::Reservation> surface_memory_;  // by surface id
  std::size_t triangles_ = 0;   // over all surfaces
  std::size_t mesh_bytes_ = 0;  // MeshBytes over all surfaces
  std::optional<Iso3> seed_;
  FrameConvention seed_frame_ = FrameConvention::kUnity;
  std::map<std::string, SessionJoints> joints_;  // latest JointState by robot id; "" applies to every robot
  MappingMotion mapping_motion_;  // each joint's range over the states sent since the first surface
  std::set<std::uint64_t> in_flight_;
  bool shutdown_notified_ = false;

  SteadyClock::time_point connected_at_ = SteadyClock::now();
  double connected_unix_s_ = 0.0;
  std::unique_ptr<wire::RecordingWriter> recorder_;
};

}  // namespace arref::server
