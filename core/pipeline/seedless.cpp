// arref-auto: the robot found in the whole map with no seed. The headset's world is gravity
// aligned and arms stand upright, so a base is (x, y, yaw) on a horizontal support: the
// detection scores every column of the map, on every support under it and every yaw, by the
// share of the robot's visible surface cells (its posed model, at a cell of a twelfth of its
// largest side) that the map occupies there; the best distinct candidates are then registered
// with arref-icp as if the user had put the seed there, which searches +-0.5 m and every yaw
// round each and rates its own fit. Every distinct fit that is not FAILED is an instance.
#include "arref/pipeline/seedless.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "arref/base/clock.h"
#include "arref/fusion/model_reconstruction.h"
#include "arref/fusion/model_visibility.h"
#include "arref/scene/nearest_neighbor.h"
#include "arref/scene/sampling.h"

namespace arref {
namespace {

constexpr double kUpCos = 0.94;         // a support faces up within about 20 degrees
constexpr double kSupportBinM = 0.02;   // height histogram bin (about a mesh's noise)
constexpr double kSupportAreaM2 = 0.05; // a support shows at least this much up-facing area
constexpr std::size_t kMaxSupports = 32;  // one bit each in a column's mask

// The robot's size, from its posed samples (base frame): nothing here assumes one robot.
struct RobotSize {
  Aabb box;
  double largest_side = 0;
  double footprint_radius = 0;  // half the diagonal of what lies in its lowest tenth, on its support
  float z_min = 0;  // the surface it stands on (RobotSide::resting_height)
};

RobotSize SizeOf(const RobotSide& robot) {
  const PointCloud& model = robot.samples();
  RobotSize s;
  for (const Vec3f& p : model.points) s.box.Extend(p);
  s.largest_side = (s.box.max - s.box.min).maxCoeff();
  s.z_min = static_cast<float>(robot.resting_height());
  // The lowest tenth above the surface it stands on: an arm reaching below that surface (from a
  // pedestal) is not what stands on it.
  const float low = s.z_min + 0.1f * (s.box.max.z() - s.z_min);
  Aabb foot;
  for (const Vec3f& p : model.points)
    if (p.z() >= s.z_min - 1e-3f && p.z() <= low) foot.Extend(p);
  s.footprint_radius = foot.valid() ? 0.5 * (foot.max - foot.min).head<2>().norm() : 0.1 * s.largest_side;
  return s;
}

// Occupancy of the map at the detection cell: which cells hold any sample.
struct Occupancy {
  Vec3 origin = Vec3::Zero();
  double cell = 0.1;
  Eigen::Vector3i dims = Eigen::Vector3i::Zero();
  std::vector<std::uint8_t> occupied;
  std::vector<std::uint32_t> supports;  // per column (x-y): bit s = support s lies within reach

  std::size_t Column(int x, int y) const { return static_cast<std::size_t>(y) * static_cast<std::size_t>(dims.x()) + static_cast<std::size_t>(x); }
  bool At(int x, int y, int z) const {
    if (x < 0 || y < 0 || z < 0 || x >= dims.x() || y >= dims.y() || z >= dims.z()) return false;
    return occupied[static_cast<std::size_t>(z) * static_cast<std::size_t>(dims.x() * dims.y()) + Column(x, y)] != 0;
  }
  Eigen::Vector3i CellOf(const Vec3& p) const { return ((p - origin) / cell).array().floor().cast<int>(); }
};

// Heights of the horizontal surfaces in the whole map: peaks of the up-facing points' height
// histogram holding at least kSupportAreaM2 of area.
std::vector<double> SupportHeights(const PointCloud& map, double points_per_m2) {
  float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
  for (std::size_t i = 0; i < map.size(); ++i)
    if (map.normals[i].z() >= kUpCos) lo = std::min(lo, map.points[i].z()), hi = std::max(hi, map.points[i].z());
  if (lo > hi) return {};
  const auto bins = static_cast<std::size_t>((hi - lo) / kSupportBinM) + 1;
  std::vector<double> count(bins, 0.0);
  for (std::size_t i = 0; i < map.size(); ++i)
    if (map.normals[i].z() >= kUpCos) count[static_cast<std::size_t>((map.points[i].z() - lo) / kSupportBinM)] += 1;
  const double min_count = kSupportAreaM2 * points_per_m2;
  std::vector<std::pair<double, double>> peaks;  // count, height
  for (std::size_t b = 0; b < bins; ++b) {
    const double left = b > 0 ? count[b - 1] : 0, right = b + 1 < bins ? count[b + 1] : 0;
    if (count[b] < min_count || count[b] < left || count[b] <= right) continue;
    // The peak's height: the mean of its bin and neighbours, weighted by their counts.
    const double sum = left + count[b] + right;
    const double z = lo + kSupportBinM * (static_cast<double>(b) + 0.5 + (right - left) / sum);
    peaks.push_back({count[b], z});
  }
  std::sort(peaks.begin(), peaks.end(), std::greater<>());
  std::vector<double> heights;
  for (const auto& [c, z] : peaks)
    if (heights.size() < kMaxSupports) heights.push_back(z);
  return heights;
}

Occupancy BuildOccupancy(const PointCloud& map, double cell, const std::vector<double>& supports, double reach_m) {
  Occupancy o;
  o.cell = cell;
  const Aabb box = BoundsOf(map.points);
  o.origin = box.min.cast<double>() - Vec3::Constant(cell);
  o.dims = (((box.max - box.min).cast<double>() / cell).array().ceil().cast<int>() + 3).matrix();
  o.occupied.assign(static_cast<std::size_t>(o.dims.prod()), 0);
  o.supports.assign(static_cast<std::size_t>(o.dims.x() * o.dims.y()), 0);
  std::vector<std::uint32_t> own(o.supports.size(), 0);  // supports seen in the column itself
  for (std::size_t i = 0; i < map.size(); ++i) {
    const Eigen::Vector3i c = o.CellOf(map.points[i].cast<double>());
    o.occupied[static_cast<std::size_t>(c.z()) * static_cast<std::size_t>(o.dims.x() * o.dims.y()) + o.Column(c.x(), c.y())] = 1;
    if (map.normals[i].z() < kUpCos) continue;
    for (std::size_t s = 0; s < supports.size(); ++s)
      if (std::abs(map.points[i].z() - supports[s]) <= 1.5 * kSupportBinM) own[o.Column(c.x(), c.y())] |= 1u << s;
  }
  // A base stands on a support that shows within its footprint's reach (the rest lies under it).
  const int r = static_cast<int>(std::ceil(reach_m / cell));
  for (int y = 0; y < o.dims.y(); ++y)
    for (int x = 0; x < o.dims.x(); ++x) {
      std::uint32_t mask = 0;
      for (int dy = -r; dy <= r; ++dy)
        for (int dx = -r; dx <= r; ++dx) {
          const int xx = x + dx, yy = y + dy;
          if (xx >= 0 && yy >= 0 && xx < o.dims.x() && yy < o.dims.y()) mask |= own[o.Column(xx, yy)];
        }
      o.supports[o.Column(x, y)] = mask;
    }
  return o;
}

// The robot's visible surface cells standing on support height z at yaw: (dx, dy) from the
// base's column, z as the occupancy's layer. The support's own layer is left out (every floor
// fills it).
std::vector<Eigen::Vector3i> Template(const PointCloud& visible, const RobotSize& size, const Occupancy& o, double support_z,
                                      double yaw) {
  const double base_z = support_z - size.z_min;
  const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
  std::vector<Eigen::Vector3i> cells;
  for (const Vec3f& p : visible.points) {
    const Vec3 q = R * p.cast<double>();
    if (base_z + q.z() < support_z + 0.75 * o.cell) continue;
    cells.push_back(Eigen::Vector3i(static_cast<int>(std::lround(q.x() / o.cell)), static_cast<int>(std::lround(q.y() / o.cell)),
                                    static_cast<int>(std::floor((base_z + q.z() - o.origin.z()) / o.cell))));
  }
  auto less = [](const Eigen::Vector3i& a, const Eigen::Vector3i& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  };
  std::sort(cells.begin(), cells.end(), less);
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  return cells;
}

struct Detection {
  double score = 0;
  Iso3 T_world_seed = Iso3::Identity();
};

// Every column on every support within its reach at every yaw, scored; the best per column.
std::vector<Detection> Detect(const Occupancy& o, const PointCloud& visible, const RobotSize& size,
                              const std::vector<double>& supports, int yaws) {
  std::vector<std::vector<std::vector<Eigen::Vector3i>>> templates(supports.size());
  for (std::size_t s = 0; s < supports.size(); ++s)
    for (int k = 0; k < yaws; ++k)
      templates[s].push_back(Template(visible, size, o, supports[s], 2 * std::numbers::pi * k / yaws));
  std::vector<Detection> best(o.supports.size());
  tbb::parallel_for(0, o.dims.y(), [&](int y) {
    for (int x = 0; x < o.dims.x(); ++x) {
      Detection& d = best[o.Column(x, y)];
      const std::uint32_t mask = o.supports[o.Column(x, y)];
      for (std::size_t s = 0; s < supports.size(); ++s) {
        if (!(mask & (1u << s))) continue;
        for (int k = 0; k < yaws; ++k) {
          const auto& cells = templates[s][static_cast<std::size_t>(k)];
          if (cells.empty()) continue;
          std::size_t hits = 0;
          for (const Eigen::Vector3i& c : cells) hits += o.At(x + c.x(), y + c.y(), c.z());
          const double score = static_cast<double>(hits) / static_cast<double>(cells.size());
          if (score > d.score) {
            const Vec3 centre = o.origin + o.cell * Vec3(x + 0.5, y + 0.5, 0);
            d = {score, MakeYawPose(centre.x(), centre.y(), supports[s] - size.z_min, 2 * std::numbers::pi * k / yaws)};
          }
        }
      }
    }
  });
  return best;
}

double Horizontal(const Iso3& a, const Iso3& b) { return (a.translation() - b.translation()).head<2>().norm(); }

// The best detections at least `apart` from each other, at most `count`.
std::vector<Detection> Distinct(std::vector<Detection> all, double apart, std::size_t count) {
  std::sort(all.begin(), all.end(), [](const Detection& a, const Detection& b) { return a.score > b.score; });
  std::vector<Detection> out;
  for (const Detection& d : all) {
    if (out.size() == count || d.score <= 0) break;
    if (std::none_of(out.begin(), out.end(), [&](const Detection& o) { return Horizontal(o.T_world_seed, d.T_world_seed) < apart; }))
      out.push_back(d);
  }
  return out;
}

// How much of the map round a fit the robot explains. A robot that is there is the surface in
// its own neighbourhood; a small model laid on clutter touches boxes, boards and walls that
// carry on past it. Of the map samples within `near` of the posed model (above its support),
// the share within `on` of it. An unrelated plane crossing the neighbourhood would be explained
// at about the chance share on / near; a robot that is there leaves unexplained only what
// happens to stand close to it (a wall, a table edge), at most half of that chance share.
struct Explanation {
  double share = 0;   // explained / near
  double chance = 0;  // on / near
  std::size_t near = 0;
  double Bar() const { return 1.0 - 0.5 * chance; }
  bool Holds() const { return near > 0 && share >= Bar(); }
};

Explanation Explain(const PointCloud& map, const PointCloud& model_base, const RobotSize& size, const Iso3& T_world_base,
                    double on, double near) {
  std::vector<Vec3f> posed;
  posed.reserve(model_base.size());
  Aabb box;
  for (const Vec3f& p : model_base.points) {
    posed.push_back((T_world_base * p.cast<double>()).cast<float>());
    box.Extend(posed.back());
  }
  const PointIndex index(std::move(posed));
  const float margin = static_cast<float>(near);
  const double floor_z = T_world_base.translation().z() + size.z_min + on;  // the support itself explains nothing
  Explanation e;
  e.chance = on / near;
  std::size_t explained = 0;
  const float near_sq = static_cast<float>(near * near), on_sq = static_cast<float>(on * on);
  for (const Vec3f& q : map.points) {
    if ((q.array() < box.min.array() - margin).any() || (q.array() > box.max.array() + margin).any() || q.z() < floor_z)
      continue;
    std::uint32_t i = 0;
    float d2 = 0;
    if (!index.NearestWithin(q, near_sq, &i, &d2)) continue;
    ++e.near;
    explained += d2 <= on_sq;
  }
  e.share = e.near > 0 ? static_cast<double>(explained) / static_cast<double>(e.near) : 0.0;
  return e;
}

// Every check of where the robot stands passed: OK, or LOW_CONFIDENCE only for its expected error.
// Such a fit is no maybe: the explanation and distinct-pose checks below are for fits that are.
bool Placed(const RegistrationReport& r) { return r.status == ResultStatus::kOk || r.imprecise_only; }

// The seedless analogue of arref-icp's margin (ConfidenceThresholds::ok_min_margin). A seeded
// search compares poses round one place the user chose; a room search tries every candidate base,
// so a fit on clutter somewhere is expected, and an OK must lead the best of those by the same
// margin: a robot that fits no better than a shelf elsewhere in the room is not evidence that it
// stands there. Clutter: fits that fail on their own (FAILED, or LOW_CONFIDENCE and unexplained),
// away from every OK fit (a failed duplicate of an arm is the same place, not an alternative).
// A demoted fit becomes LOW_CONFIDENCE and must then explain its place like any other.
void DemoteOkBelowClutter(std::vector<Result<RegistrationReport>>& fits, const std::vector<Explanation>& explained,
                          double apart, double min_lead) {
  auto is_ok = [&](std::size_t i) { return fits[i].ok() && Placed(*fits[i]); };
  double clutter = -1;
  for (std::size_t i = 0; i < fits.size(); ++i) {
    if (!fits[i].ok() || is_ok(i)) continue;
    if (fits[i]->status != ResultStatus::kFailed && explained[i].Holds()) continue;
    bool near_ok = false;
    for (std::size_t j = 0; j < fits.size(); ++j)
      near_ok = near_ok || (is_ok(j) && Horizontal(fits[j]->T_world_base, fits[i]->T_world_base) < apart);
    if (!near_ok) clutter = std::max(clutter, fits[i]->score);
  }
  if (clutter < 0) return;
  for (std::size_t i = 0; i < fits.size(); ++i) {
    if (!is_ok(i) || fits[i]->score - clutter >= min_lead) continue;
    fits[i]->status = ResultStatus::kLowConfidence;
    fits[i]->imprecise_only = false;
    fits[i]->status_reason = fmt::format(
        "ambiguous: a fit on other surfaces of the map scores almost as well (score {:.3f} against {:.3f})",
        fits[i]->score, clutter);
  }
}

// Instances: OK, then placed but imprecise, then maybes (RanksBefore orders them within a tier).
int StatusRank(const RegistrationReport& r) {
  if (r.status == ResultStatus::kOk) return 0;
  if (r.imprecise_only) return 1;
  return r.status == ResultStatus::kLowConfidence ? 2 : 3;
}

// a before b: the lower rank, then the higher score.
template <int (*Rank)(const RegistrationReport&)>
bool RankedBefore(const FoundInstance& a, const FoundInstance& b) {
  if (Rank(a.report) != Rank(b.report)) return Rank(a.report) < Rank(b.report);
  return a.report.score > b.report.score;
}

// The first tier's fits, whose order picks which of several fits of one arm seeds the second:
// placed ones by score, whether or not precise (a first-tier fit is refined anyway).
int SearchRank(const RegistrationReport& r) { return Placed(r) ? 0 : StatusRank(r); }

bool BetterStart(const FoundInstance& a, const FoundInstance& b) { return RankedBefore<SearchRank>(a, b); }

// The primary instance: the OK one nearest the hint (gaze point, else wearer), else the first.
int Primary(const std::vector<FoundInstance>& found, const InstanceHint& hint) {
  if (found.empty()) return -1;
  const std::optional<Vec3> at = hint.gaze_point_world ? hint.gaze_point_world : hint.wearer_position_world;
  if (!at) return 0;
  int best = 0;
  double best_d = std::numeric_limits<double>::max();
  for (std::size_t i = 0; i < found.size(); ++i) {
    if (StatusRank(found[i].report) != StatusRank(found.front().report)) break;  // only among the best rank
    const double d = (found[i].report.T_world_base.translation() - *at).head<2>().norm();
    if (d < best_d) best_d = d, best = static_cast<int>(i);
  }
  return best;
}

void Finish(const InstanceHint& hint, WholeMapReport* out) {
  std::stable_sort(out->instances.begin(), out->instances.end(), RanksBefore);
  out->primary = Primary(out->instances, hint);
  if (out->primary < 0) {
    out->status = ResultStatus::kFailed;
    if (out->status_reason.empty()) out->status_reason = "the robot was not found in the map";
    return;
  }
  const RegistrationReport& p = out->instances[static_cast<std::size_t>(out->primary)].report;
  out->status = p.status;
  out->status_reason = p.status_reason;
}

class Stages {
 public:
  Stages(WholeMapReport* out, const ProgressFn& progress) : out_(out), progress_(progress) {}
  void Start(const std::string& stage, double fraction) {
    Stop();
    stage_ = stage;
    laps_.Restart();
    if (progress_) progress_(stage, fraction);
  }
  void Stop() {
    if (!stage_.empty()) out_->timings.push_back({stage_, laps_.Lap()});
    stage_.clear();
  }

 private:
  WholeMapReport* out_;
  const ProgressFn& progress_;
  std::string stage_;
  LapTimer laps_;
};

Status CheckCancel(const CancelToken* cancel, const char* before) {
  if (Cancelled(cancel)) return Status::Cancelled(fmt::format("whole-map registration cancelled before {}", before));
  return Status::Ok();
}

Result<WholeMapReport> AutoSearch(const RobotSide& robot, const TriangleMesh& scene_world, const RegistrationOptions& options,
                                  const InstanceHint& hint, const ProgressFn& progress, const CancelToken* cancel) {
  const SeedlessParams& p = options.seedless;
  if (p.max_candidates < 1 || p.yaws < 1 || !(p.cell_fraction > 0) || !(p.samples_per_cell_face > 0))
    return Status::InvalidArgument("arref-auto: max_candidates, yaws, cell_fraction and samples_per_cell_face must be > 0");
  WholeMapReport out;
  out.method = "arref-auto";
  out.scene_triangles = scene_world.triangles.size();
  Stages stages(&out, progress);
  stages.Start("map-sample", 0.0);
  const double voxel = options.arref_icp.expected_voxel_m > 0 ? options.arref_icp.expected_voxel_m : MedianEdgeLength(scene_world);
  const RobotSize size = SizeOf(robot);
  const double cell = std::max(voxel, p.cell_fraction * size.largest_side);
  const double area = scene_world.SurfaceArea();
  const auto samples = static_cast<std::size_t>(std::min<double>(static_cast<double>(p.max_map_samples),
                                                                 p.samples_per_cell_face * area / (cell * cell)));
  const PointCloud map = SampleSurface(scene_world, samples, options.sample_seed);
  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "the detection"));
  stages.Start("detect", 0.1);
  const std::vector<double> supports = SupportHeights(map, static_cast<double>(samples) / std::max(area, 1e-9));
  const Occupancy occupancy = BuildOccupancy(map, cell, supports, size.footprint_radius + cell);
  const PointCloud visible = VisiblePoints(robot.samples());
  // Two bases cannot stand closer than a footprint apart.
  const double apart = std::max(2.0 * size.footprint_radius, 2.0 * cell);
  const std::vector<Detection> candidates =
      Distinct(Detect(occupancy, visible, size, supports, p.yaws), apart, p.max_candidates);
  out.candidates = static_cast<int>(candidates.size());
  out.stages_run = {"map-sample", "supports", "detect"};
  spdlog::debug("arref-auto: cell {:.3f} m, {} map samples, {} supports, {} candidates (best {:.2f})", cell, samples,
                supports.size(), candidates.size(), candidates.empty() ? 0.0 : candidates.front().score);
  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "the candidates' registrations"));
  stages.Start("candidates", 0.2);
  // Tier 1: every candidate with arref-icp's search and refinement only (no walk choice, no
  // refit in context: those cost most of a request and only polish a fit already found).
  RegistrationOptions each = options;
  each.method = Method::kArrefIcp;
  each.arref_icp.expected_voxel_m = voxel;  // one voxel for every crop: the robot's surfaces are made once
  // Every start of the yaw search settled, in both tiers: a candidate's first search is never
  // widened to positions (below), so a start pruned before it settled has nothing behind it.
  // Settling only the best 8 in both tiers lost 2 of 40 held-back rooms and said one fit 22 mm
  // off OK (docs/robustness.md, "Settling only the best captured starts").
  each.arref_icp.settle_top = std::numeric_limits<int>::max();
  RegistrationOptions search = each;
  search.arref_icp.select_walk = false;
  search.arref_icp.in_context = false;
  // The detection puts a candidate within about a cell of a base on a known support: its own
  // neighbourhood is searched (every yaw, the supports within 0.35 m of its height), not a grid.
  search.arref_icp.position_steps = 0;
  search.arref_icp.seed_error_m = std::min(search.arref_icp.seed_error_m, 0.25);
  std::vector<Result<RegistrationReport>> reports(candidates.size(), Status::Internal("not run"));
  std::atomic<std::size_t> done = 0;
  tbb::parallel_for(std::size_t{0}, candidates.size(), [&](std::size_t i) {
    reports[i] = RegisterScene(robot, scene_world, candidates[i].T_world_seed, search, {}, cancel);
    const std::size_t n = ++done;
    if (progress) progress(fmt::format("candidate {} of {}", n, candidates.size()), 0.2 + 0.5 * static_cast<double>(n) / static_cast<double>(candidates.size()));
  });
  ARREF_RETURN_IF_ERROR(CheckCancel(cancel, "ranking"));
  std::vector<FoundInstance> fits;
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    if (!reports[i].ok()) {
      if (reports[i].status().code() == StatusCode::kCancelled) return reports[i].status();
      spdlog::debug("arref-auto: candidate {}: {}", i, reports[i].status().ToString());
      continue;
    }
    fits.push_back({std::move(*reports[i]), candidates[i].score});
  }
  out.stages_run.push_back(fmt::format("search-x{}", candidates.size()));
  stages.Start("distinct", 0.7);
  std::stable_sort(fits.begin(), fits.end(), BetterStart);
  const std::size_t fitted = fits.size();
  const std::string best_reason = fits.empty() ? "" : fits.front().report.status_reason;
  std::vector<FoundInstance> distinct;
  for (FoundInstance& f : fits) {
    if (f.report.status == ResultStatus::kFailed) continue;
    const bool duplicate = std::any_of(distinct.begin(), distinct.end(), [&](const FoundInstance& o) {
      return Horizontal(o.report.T_world_base, f.report.T_world_base) < apart;
    });
    if (!duplicate) distinct.push_back(std::move(f));
  }
  // Tier 2: the full arref-icp from each distinct fit, whose status is the instance's.
  const double on = std::max(options.inlier_threshold_m, voxel);  // a map sample on the robot, at the mesh's resolution
  const double near = on + cell;                                   // round the robot, at the detection's cell
  double best_share = 0, best_bar = 1;
  int unexplained = 0;  // LOW_CONFIDENCE fits that leave too much of the map round them unexplained
  int ambiguous = 0;    // ... or that explain it but lead their alternative poses by less than an OK margin
  double best_ambiguous_margin = 0;
  stages.Start("refine", 0.75);
  std::vector<Result<RegistrationReport>> full(distinct.size(), Status::Internal("not run"));
  tbb::parallel_for(std::size_t{0}, distinct.size(), [&](std::size_t i) {
    full[i] = RegisterScene(robot, scene_world, distinct[i].report.T_world_base, each, {}, cancel);
  });
  for (const auto& f : full)
    if (!f.ok() && f.status().code() == StatusCode::kCancelled) return f.status();
  std::vector<Explanation> explained(distinct.size());
  for (std::size_t i = 0; i < distinct.size(); ++i)
    if (full[i].ok()) explained[i] = Explain(map, robot.samples(), size, full[i]->T_world_base, on, near);
  DemoteOkBelowClutter(full, explained, apart, options.confidence.ok_min_margin);
  for (std::size_t i = 0; i < distinct.size(); ++i) {
    if (!full[i].ok() || full[i]->status == ResultStatus::kFailed) continue;
    const bool duplicate = std::any_of(out.instances.begin(), out.instances.end(), [&](const FoundInstance& o) {
      return Horizontal(o.report.T_world_base, full[i]->T_world_base) < apart;
    });
    const Explanation& e = explained[i];
    spdlog::debug("arref-auto: instance at ({:.2f}, {:.2f}): {} inliers {:.3f} score {:.3f} margin {:.3f} detection {:.3f} "
                  "explained {:.3f} of {} (bar {:.3f}){}",
                  full[i]->T_world_base.translation().x(), full[i]->T_world_base.translation().y(),
                  ResultStatusName(full[i]->status), full[i]->inlier_fraction, full[i]->score, full[i]->margin,
                  distinct[i].detection_score, e.share, e.near, e.Bar(), duplicate ? " (duplicate)" : "");
    if (e.share > best_share) best_share = e.share, best_bar = e.Bar();
    // An OK fit has passed arref-icp's margin and coverage and leads the room's clutter; a
    // LOW_CONFIDENCE one is a maybe, and with several candidates per room a maybe on clutter is
    // likely, so it must explain its place, and be a distinct pose: lead its own alternatives by
    // the margin an OK fit needs. A robot that is there gives one pose (LOW_CONFIDENCE instances
    // within 20 mm of an arm led by 0.18-0.58 on dev draws 1-3); a small arm laid on boxes fits
    // several poses alike (the MH5's Open3D fits on clutter led by 0.005-0.046 in empty rooms of
    // dev draws 4-13, explaining their place at 0.78-0.83 against bars of 0.76-0.81).
    if (!Placed(*full[i]) && !e.Holds()) {
      ++unexplained;
      continue;
    }
    if (!Placed(*full[i]) && full[i]->margin < options.confidence.ok_min_margin) {
      ++ambiguous;
      best_ambiguous_margin = std::max(best_ambiguous_margin, full[i]->margin);
      continue;
    }
    if (!duplicate) out.instances.push_back({std::move(*full[i]), distinct[i].detection_score, e.share, e.Bar()});
  }
  out.stages_run.push_back(fmt::format("arref-icp-x{}", distinct.size()));
  if (out.instances.empty() && ambiguous > 0 && unexplained == 0)
    out.status_reason = fmt::format(
        "none of the {} candidate bases gave a distinct pose of the robot: the best led its alternative poses by "
        "{:.3f} (a robot that is there leads by {:.2f} or more), so it lies on other surfaces",
        fitted, best_ambiguous_margin, options.confidence.ok_min_margin);
  else if (out.instances.empty() && unexplained > 0)
    out.status_reason = fmt::format(
        "none of the {} candidate bases explained the robot: the best fit left {:.0f} % of the map round it off the "
        "robot (at most {:.0f} % for a robot that is there), so it lies on other surfaces",
        fitted, 100 * (1 - best_share), 100 * (1 - best_bar));
  else if (out.instances.empty())
    out.status_reason = fitted == 0 ? "no candidate base was found in the map"
                                    : fmt::format("none of the {} candidate bases explained the robot (best: {})", fitted,
                                                  best_reason.empty() ? "a LOW_CONFIDENCE fit that did not hold" : best_reason);
  stages.Stop();
  Finish(hint, &out);
  if (progress) progress("done", 1.0);
  return out;
}

// A seeded method (or the sliding box, which ignores its seed) run once over the whole map:
// seeded at the map's centre on its lowest floor, the crop holding all of it.
Result<WholeMapReport> WholeMapOnce(const RobotSide& robot, const TriangleMesh& scene_world, const RegistrationOptions& options,
                                    const InstanceHint& hint, const ProgressFn& progress, const CancelToken* cancel) {
  WholeMapReport out;
  const MethodInfo* info = FindMethod(options.method);
  out.method = info ? info->name : "unavailable-method";
  out.scene_triangles = scene_world.triangles.size();
  const Aabb box = BoundsOf(scene_world.vertices);
  if (!box.valid()) return Status::FailedPrecondition("the map is empty");
  const Vec3 centre = (0.5 * (box.min + box.max)).cast<double>();
  RegistrationOptions once = options;
  // The paper's segmentation keeps the cluster nearest the seed: with no seed it would keep
  // whatever stands at the map's centre, so the global methods align against the whole map.
  once.segmentation.enabled = false;
  once.crop_radius_m = 0.5 * (box.max - box.min).cast<double>().norm() + 0.1;
  // As dense as a 2 m crop's samples (about 25 m^2 of surface), within the map limit.
  const double area = scene_world.SurfaceArea();
  once.scene_samples = static_cast<std::size_t>(std::clamp(static_cast<double>(options.scene_samples) * area / 25.0,
                                                           static_cast<double>(options.scene_samples),
                                                           static_cast<double>(options.seedless.max_map_samples)));
  ARREF_ASSIGN_OR_RETURN(RegistrationReport report,
                         RegisterScene(robot, scene_world, MakeYawPose(centre.x(), centre.y(), box.min.z(), 0.0), once, progress, cancel));
  out.timings = report.timings;
  out.stages_run = report.stages_run;
  out.candidates = 1;
  if (report.status != ResultStatus::kFailed) out.instances.push_back({std::move(report), 0.0});
  else out.status_reason = report.status_reason;
  Finish(hint, &out);
  return out;
}

}  // namespace

// Two placed but imprecise fits both lie on the map (they passed every other test), and a fit
// over the map's flat parts can hold more of the model within 2 cm than a better placed one: the
// score ranks how much lies on the map, the expected error how well it is placed.
bool RanksBefore(const FoundInstance& a, const FoundInstance& b) {
  // An unmeasured (non-finite) figure counts as the largest: a NaN would break the sort's order.
  auto expected = [](const FoundInstance& f) {
    const double e = f.report.precision.expected_error_m;
    return std::isfinite(e) ? e : std::numeric_limits<double>::infinity();
  };
  if (a.report.imprecise_only && b.report.imprecise_only && expected(a) != expected(b)) return expected(a) < expected(b);
  return RankedBefore<StatusRank>(a, b);
}

double WholeMapReport::total_ms() const {
  double total = 0;
  for (const auto& t : timings) total += t.ms;
  return total;
}

Result<WholeMapReport> RegisterWholeMap(const RobotSide& robot, const TriangleMesh& scene_world, const RegistrationOptions& options,
                                        const InstanceHint& hint, const ProgressFn& progress, const CancelToken* cancel) {
  if (scene_world.empty()) return Status::FailedPrecondition("the map holds no triangles: nothing to search");
  for (const auto& at : {hint.gaze_point_world, hint.wearer_position_world})
    if (at && !at->allFinite()) return Status::InvalidArgument("the instance hint is not finite");
  if (options.method == Method::kArrefAuto) return AutoSearch(robot, scene_world, options, hint, progress, cancel);
  if (!FindMethod(options.method))
    return Status::InvalidArgument("registration method not built in (arref was built without ARREF_WITH_PCL)");
  return WholeMapOnce(robot, scene_world, options, hint, progress, cancel);
}

}  // namespace arref
