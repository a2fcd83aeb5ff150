// One ICP iteration: arref's kernel (point-to-plane, and point-to-point like PCL's) against
// PCL 1.13's ICP, on the same simulated small-configuration KR5 cell (16,000 scene points).
// The hardware floor of a nearest-neighbour ICP iteration is N_source x ~150 ns / threads; the counters
// report ns per source point.
//   build/bench/arref_icp_benchmark --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <map>
#include <memory>
#include <thread>
#include <utility>

#include "arref/base/builtin.h"
#include "arref/base/cancel.h"
#include "arref/icp/fast_icp.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/fusion/model_visibility.h"
#include "arref/pipeline/pipeline.h"
#include "arref/scene/sampling.h"
#include "arref/sim/cell_simulator.h"
#include "arref/sim/track_simulator.h"
#include "arref/track/depth_noise.h"
#include "arref/track/model_caster.h"
#include "arref/track/tracker.h"
#include "arref/scene/spatial_mesh.h"
#include "arref/fusion/tracking_error.h"
#include "arref/fusion/tsdf.h"

namespace arref {
namespace {

struct Fixture {
  PointCloud model;  // visible robot points, base frame
  PointCloud scene;  // 16,000 world points with normals
  TriangleMesh scene_mesh;  // the headset's mesh, world frame
  TriangleMesh cropped;     // 2 m round the robot, as a request crops it
  double voxel_m = 0.0;     // the headset mesh's voxel (median edge length)
  Iso3 T_world_base;
  Iso3 T_world_seed;  // a user-like seed
  std::shared_ptr<const RobotModel> model_robot;
  JointValues joints;
  std::shared_ptr<const RobotSide> robot;
  std::vector<Vec3> head_path_world;  // where the simulated user walked
};

const Fixture& Cell() {
  static const Fixture f = [] {
    auto loaded = RobotModel::Load(*BuiltinRobotUrdf());
    auto robot = std::make_shared<const RobotModel>(std::move(*loaded));
    auto cell = sim::SimulateCell(*robot, sim::SmallPreset(), 1);
    SpatialMesh map;
    for (auto& s : cell->surfaces) (void)map.Upsert(s);
    Fixture out;
    out.T_world_base = cell->T_world_base;
    auto model = SampleRobot(*robot, cell->joints, 10000, 1);
    out.model = VisiblePoints(*model);
    out.scene_mesh = *map.MergedWorld();
    out.cropped = CropToSphere(out.scene_mesh, cell->T_world_base.translation(), 2.0);
    out.voxel_m = MedianEdgeLength(out.cropped);
    out.scene = SampleSurface(out.cropped, 16000, 1);
    out.T_world_seed = cell->seeds.front();
    out.model_robot = robot;
    out.joints = cell->joints;
    out.head_path_world = cell->head_path_world;
    out.robot = *RobotSide::Create(*robot, cell->joints, 10000, 1);
    return out;
  }();
  return f;
}

PointCloud FirstN(const PointCloud& c, std::size_t n) {
  std::vector<std::uint32_t> keep;
  for (std::size_t i = 0; i < std::min(n, c.size()); ++i) keep.push_back(static_cast<std::uint32_t>(i));
  return c.Subset(keep);
}

// 1 cm off the truth, as in the last iterations of a registration.
Iso3 NearTruth() { return MakeYawPose(0.01, 0, 0, 0) * Cell().T_world_base; }

// Arguments: source points, threads, metric (0 point-to-plane, 1 point-to-point).
void BM_ArrefIteration(benchmark::State& state) {
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(state.range(1)));
  // In the order arref-icp queries them (SpatiallyOrdered, as its Thin does).
  const PointCloud source = SpatiallyOrdered(FirstN(Cell().model, static_cast<std::size_t>(state.range(0))));
  const TargetCloud target(Cell().scene);
  IcpSettings s;
  s.metric = state.range(2) == 0 ? IcpMetric::kPointToPlane : IcpMetric::kPointToPoint;
  s.max_iterations = 1;
  s.max_correspondence_m = 0.05;
  for (auto _ : state) benchmark::DoNotOptimize(Align(source, target, NearTruth(), s));
  // Seconds per source point per iteration (printed with an SI prefix, e.g. 120n).
  state.counters["per_point"] = benchmark::Counter(static_cast<double>(source.size()),
                                                   benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  state.counters["floor_ms"] = static_cast<double>(source.size()) * 150e-6 / static_cast<double>(state.range(1));
}

// Ten iterations of one level from near the truth, as arref-icp runs a level: BM_ArrefIteration
// is the first of them, where every point searches the tree; after it, each point's search starts
// from the neighbourhood its last one kept (MovingNearest). per_point is per point and iteration.
void BM_ArrefTenIterations(benchmark::State& state) {
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(state.range(1)));
  const PointCloud source = SpatiallyOrdered(FirstN(Cell().model, static_cast<std::size_t>(state.range(0))));
  const TargetCloud target(Cell().scene);
  IcpSettings s;
  s.max_iterations = 10;
  s.max_correspondence_m = 0.05;
  s.converged_translation_m = s.converged_rotation_rad = s.converged_cost_ratio = 0;  // all ten
  int iterations = 0;
  for (auto _ : state) iterations = Align(source, target, NearTruth(), s).iterations;
  if (iterations != s.max_iterations) state.SkipWithError("the level stopped before its tenth iteration");
  state.counters["per_point"] = benchmark::Counter(static_cast<double>(source.size()) * s.max_iterations,
                                                   benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  state.counters["floor_ms"] = static_cast<double>(source.size()) * 150e-6 / static_cast<double>(state.range(1));
}

pcl::PointCloud<pcl::PointXYZ>::Ptr ToPcl(const PointCloud& c) {
  auto out = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  for (const auto& p : c.points) out->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  return out;
}

// PCL ICP is single-threaded; one align() with one iteration, target tree built once.
void BM_PclIteration(benchmark::State& state) {
  const PointCloud source = FirstN(Cell().model, static_cast<std::size_t>(state.range(0)));
  pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> icp;
  icp.setInputSource(ToPcl(source));
  icp.setInputTarget(ToPcl(Cell().scene));
  icp.setMaxCorrespondenceDistance(0.1);
  icp.setMaximumIterations(1);
  const Eigen::Matrix4f guess = NearTruth().matrix().cast<float>();
  pcl::PointCloud<pcl::PointXYZ> aligned;
  for (auto _ : state) {
    icp.align(aligned, guess);
    benchmark::DoNotOptimize(aligned);
  }
  state.counters["per_point"] = benchmark::Counter(static_cast<double>(source.size()),
                                                   benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

// One request end to end as the server runs it (crop, sample, register, evaluate), with the
// robot side's cached surfaces already made. Args: the refit in context (1) or not (0), and
// its last polish as by default (1) or as before either had a setting of its own (0: 2,000
// points against the request's scene samples); optional third: the request sends the user's
// head path (1) or not (0, the default).
void BM_Request(benchmark::State& state) {
  RegistrationOptions options;
  options.arref_icp.in_context = state.range(0) != 0;
  if (state.range(1) == 0) {
    options.arref_icp.context_points = 2000;
    options.arref_icp.context_target_density = 0.0;
  }
  const Fixture& f = Cell();
  if (state.range(2) != 0) options.head_path_world = f.head_path_world;
  auto warm = RegisterScene(*f.robot, f.scene_mesh, f.T_world_seed, options);
  if (!warm.ok()) return state.SkipWithError(warm.status().ToString().c_str());
  for (auto _ : state) benchmark::DoNotOptimize(RegisterScene(*f.robot, f.scene_mesh, f.T_world_seed, options));
}

// How soon a cancel takes effect: a request (as BM_Request's default) is cancelled from another
// thread the argument's milliseconds after it started; the time reported is from Cancel() to
// RegisterScene's return (manual time). Counter "finished": runs done before the cancel came.
void BM_CancelLatency(benchmark::State& state) {
  const Fixture& f = Cell();
  const RegistrationOptions options;
  auto warm = RegisterScene(*f.robot, f.scene_mesh, f.T_world_seed, options);
  if (!warm.ok()) return state.SkipWithError(warm.status().ToString().c_str());
  int finished = 0;
  for (auto _ : state) {
    CancelToken token;
    std::chrono::steady_clock::time_point cancelled_at;
    std::thread canceller([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(state.range(0)));
      cancelled_at = std::chrono::steady_clock::now();
      token.Cancel();
    });
    const auto report = RegisterScene(*f.robot, f.scene_mesh, f.T_world_seed, options, {}, &token);
    const auto end = std::chrono::steady_clock::now();
    canceller.join();
    if (report.ok()) ++finished;  // done before the cancel: no latency to measure
    state.SetIterationTime(report.ok() ? 0.0 : std::chrono::duration<double>(end - cancelled_at).count());
  }
  state.counters["finished"] = finished;
}

// The refit's expected surface alone: the chosen walk fused again with the mapped objects.
void BM_ExpectedInContext(benchmark::State& state) {
  const Fixture& f = Cell();
  for (auto _ : state) benchmark::DoNotOptimize(f.robot->ExpectedInContext(f.voxel_m, 0, f.cropped, f.T_world_base));
}

// Which voxels of the refit's volume lie in the band round the robot (VoxelRows): made per
// volume, so per request, and paid out of what fusing only those voxels saves.
void BM_BandVoxelRows(benchmark::State& state) {
  const Fixture& f = Cell();
  const std::vector<Vec3f> robot = SampleSurface(*f.model_robot->PosedMesh(f.joints), 20000, 1).points;
  const ReconstructionOptions o;  // the band as ExpectedSurfaceMaker::Volume makes it
  const double margin = std::max(o.truncation_voxels * f.voxel_m, o.min_truncation_m) + 2 * f.voxel_m;
  for (auto _ : state) benchmark::DoNotOptimize(VoxelRows::Of(robot, f.voxel_m, margin + f.voxel_m));
}

// The last polish's weights (tracking_error.h) for its 5,000 points from the refit's 24 eyes.
void BM_TrackingErrorWeights(benchmark::State& state) {
  const Fixture& f = Cell();
  const PointCloud surface = Thinned(*f.robot->ExpectedInContext(f.voxel_m, 0, f.cropped, f.T_world_base), 5000);
  const std::vector<Vec3> eyes = RobotSide::RefitEyes(0);
  for (auto _ : state) benchmark::DoNotOptimize(TrackingErrorWeights(surface, eyes, {}));
}

// A second of the built-in robot's stream (long-throw: 320x288 at 30 fps; AHAT: 512x512 at
// 45 fps, wrapped at 1 m; no jump), as the tracker gets it: frames, the joints at their exposure,
// the first guess, and the robot's model seen from each frame's camera at the truth (what a
// wrapped frame's noise is measured against, as the filter's view of it).
struct TrackStream {
  std::shared_ptr<const RobotModel> robot;
  std::vector<sim::SimFrame> frames;
  std::vector<ModelView> views;
  Iso3 first_guess;
};

const TrackStream& SecondOf(sim::FrameKind kind) {
  static std::map<sim::FrameKind, TrackStream> streams;
  if (auto it = streams.find(kind); it != streams.end()) return it->second;
  TrackStream out;
  out.robot = Cell().model_robot;
  sim::TrackSimOptions options;
  options.kind = kind;
  options.duration_s = 1.0;
  options.jump_at_s = 10.0;
  auto simulator = sim::TrackSimulator::Create(out.robot, options, 3);
  auto caster = ModelCaster::Create(*out.robot);
  if (!simulator.ok() || !caster.ok()) return streams.emplace(kind, std::move(out)).first->second;  // no frames: skipped
  out.first_guess = simulator->T_world_base_guess();
  for (int i = 0; i < simulator->frame_count(); ++i) {
    auto f = simulator->Next();
    if (!f.ok() || !caster->Pose(*out.robot, f->joints_true).ok()) break;
    const int stride = std::max(1, (f->frame.intrinsics.width + 159) / 160);  // the tracker's default grid (StrideFor)
    out.views.push_back(caster->Render(f->frame.intrinsics, f->T_world_base_true.inverse() * f->frame.T_world_camera, 5.0, stride));
    out.frames.push_back(std::move(*f));
  }
  return streams.emplace(kind, std::move(out)).first->second;
}

sim::FrameKind KindOf(const benchmark::State& state) {
  return state.range(0) == 0 ? sim::FrameKind::kLongThrow : sim::FrameKind::kAhat;
}

// The baseline of BM_FrameDepthNoise: the tracker's whole work on those frames, per frame.
// Argument: 0 long-throw, 1 AHAT.
void BM_TrackerFrame(benchmark::State& state) {
  const TrackStream& s = SecondOf(KindOf(state));
  if (s.frames.empty()) return state.SkipWithError("the simulated stream could not be made");
  for (auto _ : state) {
    auto tracker = Tracker::Create(s.robot, {});
    if (!tracker.ok()) return state.SkipWithError(tracker.status().ToString().c_str());
    tracker->Seed(s.first_guess);
    for (const sim::SimFrame& f : s.frames) benchmark::DoNotOptimize(tracker->Process(f.frame, f.joints_true));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(s.frames.size()));
}

// What measuring a frame's depth noise adds to each frame: FrameDepthNoise on a long-throw frame,
// WrappedFrameDepthNoise on an AHAT frame (its model view made beforehand, as the tracker's fit
// makes it anyway). Argument: 0 long-throw, 1 AHAT.
void BM_FrameDepthNoise(benchmark::State& state) {
  const TrackStream& s = SecondOf(KindOf(state));
  if (s.frames.empty()) return state.SkipWithError("the simulated stream could not be made");
  for (auto _ : state)
    for (std::size_t i = 0; i < s.frames.size(); ++i)
      benchmark::DoNotOptimize(s.frames[i].frame.wrap_m > 0 ? WrappedFrameDepthNoise(s.frames[i].frame, s.views[i])
                                                            : FrameDepthNoise(s.frames[i].frame));
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(s.frames.size()));
}

// What a new joint state costs arref-icp before its first request: the posed robot and its
// expected surfaces (all round and the eight walks) at the headset's voxel.
void BM_NewJointState(benchmark::State& state) {
  const Fixture& f = Cell();
  for (auto _ : state) {
    auto side = RobotSide::Create(*f.model_robot, f.joints, 10000, 1);
    if (!side.ok()) return state.SkipWithError(side.status().ToString().c_str());
    for (int walk = -1; walk < RobotSide::kWalks; ++walk) benchmark::DoNotOptimize((*side)->Expected(f.voxel_m, walk));
  }
}

// The baseline of BM_NewJointState: its nine surfaces made one by one, as before they shared a
// lattice of eyes: 24 eyes each, walks of 220 degrees.
void BM_NewJointStateOneByOne(benchmark::State& state) {
  const Fixture& f = Cell();
  for (auto _ : state) {
    auto side = RobotSide::Create(*f.model_robot, f.joints, 10000, 1);
    auto posed = f.model_robot->PosedMesh(f.joints);
    if (!side.ok() || !posed.ok()) return state.SkipWithError("cannot pose the robot");
    auto maker = ExpectedSurfaceMaker::Create(*posed, 1);
    if (!maker.ok()) return state.SkipWithError(maker.status().ToString().c_str());
    for (int walk = -1; walk < RobotSide::kWalks; ++walk) {
      ReconstructionOptions options;
      options.voxel_m = f.voxel_m;
      if (walk >= 0) options.arc_deg = 220, options.arc_center_deg = 45.0 * walk;
      benchmark::DoNotOptimize(maker->Make(options, (*side)->samples().size()));
    }
  }
}

// A room's map as a headset streams it: 226 surfaces of about 1,500 triangles (the 341,000
// triangles of `arref-mock-headset --room --room-arms 2 --rng-seed 6`). Arg 0: SpatialMesh's
// merge, which a request does once the map changed (on the session's strand, before the job is
// queued); arg 1: the baseline, the same vertices moved into the world and copied into vectors
// reserved once, in the same run.
void BM_MergedWorld(benchmark::State& state) {
  constexpr int kSurfaces = 226, kSide = 28;  // 28 x 28 vertices: 1,458 triangles a surface
  SpatialMesh map;
  for (int s = 0; s < kSurfaces; ++s) {
    Surface surface;
    surface.id = static_cast<std::uint64_t>(s + 1);
    for (int v = 0; v < kSide; ++v)
      for (int u = 0; u < kSide; ++u) surface.mesh.vertices.emplace_back(0.05f * u, 0.05f * v, 0.01f * ((u * v) % 3));
    for (std::uint32_t v = 0; v + 1 < kSide; ++v)
      for (std::uint32_t u = 0; u + 1 < kSide; ++u) {
        const std::uint32_t i = v * kSide + u;
        surface.mesh.triangles.push_back({i, i + 1, i + kSide});
        surface.mesh.triangles.push_back({i + 1, i + kSide + 1, i + kSide});
      }
    surface.T_world_surface = MakeYawPose(1.4 * (s % 15), 1.4 * (s / 15), 0.0, 0.1 * s);
    if (!map.Upsert(std::move(surface)).ok()) return state.SkipWithError("bad surface");
  }
  const Surface first = map.surfaces().begin()->second;
  std::size_t triangles = 0;
  for (auto _ : state) {
    if (state.range(0) == 0) {
      state.PauseTiming();
      if (!map.Upsert(first).ok()) return state.SkipWithError("bad surface");  // the map changed: merge again
      state.ResumeTiming();
      triangles = map.MergedWorld()->triangles.size();
    } else {
      std::size_t v_total = 0, t_total = 0;
      for (const auto& [id, s] : map.surfaces()) v_total += s.mesh.vertices.size(), t_total += s.mesh.triangles.size();
      TriangleMesh merged;
      merged.vertices.reserve(v_total), merged.triangles.reserve(t_total);
      for (const auto& [id, s] : map.surfaces()) {
        const auto offset = static_cast<std::uint32_t>(merged.vertices.size());
        const Eigen::Isometry3f T = s.T_world_surface.cast<float>();
        for (const Vec3f& v : s.mesh.vertices) merged.vertices.push_back(T * v);
        for (const Triangle& t : s.mesh.triangles) merged.triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
      }
      triangles = merged.triangles.size();
    }
    benchmark::DoNotOptimize(triangles);
  }
  state.counters["triangles"] = static_cast<double>(triangles);
}

// Wall time, and the CPU time of every thread: their ratio is how many of the cores the step keeps
// busy (a ratio near the core count leaves nothing for more parallelism to gain).
BENCHMARK(BM_Request)->Args({1, 1, 0})->Args({1, 0, 0})->Args({0, 1, 0})->Args({1, 1, 1})->MeasureProcessCPUTime()->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_CancelLatency)->Arg(5)->Arg(30)->Arg(80)->Arg(150)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_NewJointState)->MeasureProcessCPUTime()->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_NewJointStateOneByOne)->MeasureProcessCPUTime()->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ExpectedInContext)->MeasureProcessCPUTime()->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_BandVoxelRows)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_TrackerFrame)->Arg(0)->Arg(1)->MeasureProcessCPUTime()->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_MergedWorld)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FrameDepthNoise)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_TrackingErrorWeights)->MeasureProcessCPUTime()->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ArrefIteration)->ArgsProduct({{2000, 5000}, {1, 2}, {0, 1}})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ArrefTenIterations)->ArgsProduct({{2000, 5000}, {1, 2}})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PclIteration)->Arg(2000)->Arg(5000)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace arref

BENCHMARK_MAIN();
