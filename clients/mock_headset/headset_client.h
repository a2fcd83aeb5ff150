// A headset-side client of arref-server, behaving like the HoloLens app: streams its spatial
// map as Unity-convention surfaces in batches, places the seed, asks for a registration and
// reads progress and the result. Blocking sockets, one thread per headset. Shared by the
// arref-mock-headset tool and the integration tests.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "arref/scene/metrics.h"
#include "arref/robot/robot_model.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/base/status.h"
#include "client_tls.h"
#include "recording.h"
#include "wire.h"

namespace arref::headset {

namespace pb = wire::pb;

// One blocking TCP connection exchanging arref.v1 frames, over TLS when tls.enabled.
class Connection {
 public:
  // rcvbuf_bytes > 0 shrinks the socket's receive buffer (to make a non-reading client stall sooner).
  static Result<Connection> Connect(const std::string& host, std::uint16_t port, double timeout_s,
                                    int rcvbuf_bytes = 0, const TlsClientOptions& tls = {});
  Connection() = default;  // not connected
  Connection(Connection&& other) noexcept;
  Connection& operator=(Connection&& other) noexcept;
  ~Connection();

  Status Send(const pb::ClientMessage& message);
  Status SendRaw(const std::string& bytes);
  // The next server message within timeout_s. kUnavailable: the server closed the connection;
  // kResourceExhausted: timed out.
  Result<pb::ServerMessage> Receive(double timeout_s);
  void Close();
  // Half-closes: the server sees the end of the stream but can still answer.
  void ShutdownWrite();
  bool open() const { return fd_ >= 0; }

 private:
  explicit Connection(int fd) : fd_(fd) {}
  Status ReadSome(double timeout_s);  // appends to rx_
  int fd_ = -1;
  std::string rx_;
  std::unique_ptr<ClientTls> tls_;
};

// What the headset has mapped (internal frame), and the truth when it is known.
struct HeadsetScene {
  std::vector<Surface> surfaces;
  std::vector<Iso3> seeds;               // T_world_seed guesses; none: seedless requests (the whole map)
  std::optional<Iso3> T_world_base_true;
  JointValues joints;                    // robot joint state (sent as JointState when non-empty)
  std::vector<Vec3f> model_points;       // robot points in its base frame, for ADD
  std::vector<Vec3> head_path_world;     // where the wearer walked while mapping (sent as head_path)
  std::vector<Iso3> arms_true;           // a room's: every arm of the requested model (candidates' errors)
};

// A simulated cell of the built-in robot (small preset), as the mock headset maps it.
Result<HeadsetScene> SimulatedScene(std::uint64_t rng_seed);
// A simulated room (sim/room_simulator.h) holding `arms` arms of the built-in robot (0-2), mapped
// with `mesher` ("own" or "open3d"): no seed, so the headset asks for a seedless registration.
Result<HeadsetScene> SimulatedRoomScene(std::uint64_t rng_seed, int arms, const std::string& mesher);
// A mesh file split into 1 m HoloLens-like surfaces; truth_json (optional) is `arref simulate`'s.
// The errors against that truth are measured on truth_robot_urdf (empty: the built-in robot),
// which must be the robot the cell was simulated with.
Result<HeadsetScene> SceneFromFiles(const std::string& mesh_path, FrameConvention mesh_frame,
                                    const std::string& truth_json, const std::optional<Iso3>& seed,
                                    const std::string& truth_robot_urdf = "", const RobotLoadOptions& truth_robot = {});

enum class Misbehaviour { kNone, kDisconnectMidUpload, kCorruptFrame, kOversizedMessage, kNeverReadReplies };

struct HeadsetOptions {
  std::string host = "127.0.0.1";
  std::uint16_t port = 7311;
  std::string robot_id = "kr5";
  std::string client_name = "arref-mock-headset";
  std::string auth_token;
  TlsClientOptions tls;
  std::uint32_t protocol_version = wire::kProtocolVersion;
  int seed_index = 0;
  int batches = 3;                 // the map arrives in this many batches ...
  double batch_interval_s = 0.05;  // ... this far apart
  double resend_fraction = 0.2;    // surfaces of the first batch re-sent as updates in the last
  double quantize_scale = 0.0;     // > 0: int16 vertices with this step (m)
  int repeat = 1;                  // registrations on the same session
  bool new_seed_each_repeat = false;  // each repeat moves the seed to the scene's next one first
  std::uint64_t first_request_id = 1;
  std::string method;              // "" = server default
  bool send_head_path = true;      // RegisterRequest.head_path, when the scene has one
  double timeout_s = 300.0;        // per reply; only to avoid hanging forever
  Misbehaviour misbehaviour = Misbehaviour::kNone;
  std::function<void(const pb::Progress&)> on_progress;
};

struct RegistrationOutcome {
  std::uint64_t request_id = 0;
  pb::Result result;
  Iso3 T_world_base = Iso3::Identity();  // converted back from the Unity pose
  double latency_ms = 0.0;               // last byte of the request sent -> result received
  std::optional<PoseError> error;        // against the truth, when known (a room: the arm nearest the pose)
  std::vector<double> candidate_add_m;   // a room's: each Result.candidates' ADD to its nearest arm
};

struct HeadsetRun {
  Status status;  // OK only when every registration came back OK
  std::uint64_t session_id = 0;
  std::vector<RegistrationOutcome> registrations;
  std::vector<pb::Error> errors;  // every Error the server sent
  bool got_shutdown = false;      // the server announced a shutdown
  bool server_closed = false;     // the server closed the connection
};

HeadsetRun RunHeadset(const HeadsetScene& scene, const HeadsetOptions& options);

// Sends a recorded session (wire/recording.h) to a live server: its Hello with options'
// client_name and auth_token (a recording holds no token), then every other message at its
// recorded time after the first (kOriginal) or back to back (kFast); then waits for the Result of
// every accepted request. Registrations keep the recorded request ids.
enum class Pace { kOriginal, kFast };
HeadsetRun SendRecording(const wire::Recording& recording, const HeadsetOptions& options, Pace pace);

// Many headsets at once (one thread each, seed i % seeds), for load tests and latency figures.
std::vector<HeadsetRun> RunHeadsets(const HeadsetScene& scene, const HeadsetOptions& options, int clients);

struct LatencySummary {
  std::size_t count = 0;
  double median_ms = 0.0;
  double p95_ms = 0.0;
  double max_ms = 0.0;
};
LatencySummary SummarizeLatency(const std::vector<HeadsetRun>& runs);

}  // namespace arref::headset
