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
#include "frame_decoder.h"
#include "job_scheduler.h"
#include "robot_registry.h"
#include "server_config.h"
#include "subscriber_hub.h"
#include "tracking_service.h"
#include "wire.h"

namespace arref::server {

namespace net = boost::asio;
using tcp = net::ip::tcp;

// What every session shares: set up once by the server.
struct ServerContext {
  const ServerConfig& config;
  RobotRegistry& robots;
  JobScheduler& jobs;
  SubscriberHub& hub;
  TrackingService& tracking;
  std::atomic<bool>& shutting_down;
  std::function<void(std::uint64_t session_id)> on_session_closed;
  std::string server_version;
};

class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(tcp::socket socket, ServerContext& context, std::uint64_t id);
  ~Session();

  std::uint64_t id() const { return id_; }
  void Start();
  // Rejects the connection with a fatal error (e.g. too many sessions).
  void Reject(wire::pb::ErrorCode code, const std::string& message);

  // Thread-safe: these post onto the session's strand.
  void SendFrame(std::shared_ptr<const std::string> frame);
  void DeliverResult(std::uint64_t request_id, std::shared_ptr<const std::string> frame);
  void NotifyShutdown(double grace_s);
  void CloseGracefully(const std::string& reason);

 private:
  enum class State { kAwaitHello, kReady, kClosing, kClosed };

  // Reading and framing.
  void ReadMore();
  void OnRead(const boost::system::error_code& ec, std::size_t bytes);
  bool ProcessFrames();  // false when the session started closing
  void ArmIdleTimer();

  // Message handlers.
  void Handle(const wire::pb::ClientMessage& message);
  void OnHello(const wire::pb::Hello& m);
  void OnSurfaceUpsert(const wire::pb::SurfaceUpsert& m);
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
  void CloseNow(const std::string& reason);  // drops unsent data

  tcp::socket socket_;
  ServerContext& ctx_;
  const std::uint64_t id_;
  State state_ = State::kAwaitHello;
  std::string peer_;
  std::string client_name_;
  std::string close_reason_;

  wire::FrameDecoder rx_;
  net::steady_timer idle_timer_;
  net::steady_timer write_timer_;
  net::steady_timer linger_timer_;

  std::deque<std::shared_ptr<const std::string>> write_queue_;
  std::size_t write_queue_bytes_ = 0;
  bool writing_ = false;

  SpatialMesh spatial_;
  std::optional<Iso3> seed_;
  FrameConvention seed_frame_ = FrameConvention::kUnity;
  std::map<std::string, JointValues> joints_;  // by robot id; "" applies to every robot
  // Per robot id, each joint's lowest and highest value sent since the first surface arrived.
  std::map<std::string, std::map<std::string, std::pair<double, double>>> joint_range_;
  double JointMotionWhileMapping(const std::string& robot_id) const;
  std::set<std::uint64_t> in_flight_;
  bool shutdown_notified_ = false;
};

}  // namespace arref::server
