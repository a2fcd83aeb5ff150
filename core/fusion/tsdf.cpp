#include "arref/fusion/tsdf.h"

#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <unordered_set>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace arref {
namespace {

constexpr int B = TsdfVolume::kBlock;
constexpr int kVoxelsPerBlock = B * B * B;
constexpr int kKeyBias = 1 << 20;
// Caps the weight so that old observations do not freeze the surface forever.
constexpr float kMaxWeight = 64.0f;

int LocalIndex(int x, int y, int z) { return x + B * (y + B * z); }

int FloorDiv(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

// Moves local coordinates in [-1, B] into the neighbour block that holds them; returns its slot.
int NeighbourSlot(int& x, int& y, int& z) {
  const int dx = x < 0 ? -1 : (x >= B ? 1 : 0);
  const int dy = y < 0 ? -1 : (y >= B ? 1 : 0);
  const int dz = z < 0 ? -1 : (z >= B ? 1 : 0);
  x -= dx * B;
  y -= dy * B;
  z -= dz * B;
  return (dx + 1) + 3 * (dy + 1) + 9 * (dz + 1);
}

// Splits the quad along its shorter diagonal: flatter triangles, same winding.
void EmitQuad(const std::array<std::uint32_t, 4>& q, const std::vector<Vec3f>& vertices,
              std::vector<Triangle>& out) {
  const auto& p = vertices;
  const bool diag02 = (p[q[0]] - p[q[2]]).squaredNorm() <= (p[q[1]] - p[q[3]]).squaredNorm();
  const Triangle t1 = diag02 ? Triangle{q[0], q[1], q[2]} : Triangle{q[0], q[1], q[3]};
  const Triangle t2 = diag02 ? Triangle{q[0], q[2], q[3]} : Triangle{q[1], q[2], q[3]};
  for (const Triangle& t : {t1, t2})
    if ((p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]).squaredNorm() > 1e-20f) out.push_back(t);
}

// Camera-frame depth, image position and distance from the camera of the voxels row + x * dx,
// x = 0..N-1, as UpdateVoxelsFast computes them one by one: u = f * p.x / p.z + cx (as
// f * p.x * (1 / p.z) + cx), and |p| as Eigen's norm, sqrt(x^2 + (y^2 + z^2)). With SSE, four
// lanes at a time: packed and scalar adds, multiplies, divisions and square roots round alike.
template <int N>
struct RowOfVoxels {
  alignas(16) std::array<float, N> z, u, v, distance;
  RowOfVoxels(const Vec3f& row, const Vec3f& dx, float f, float cx, float cy) {
#if defined(__SSE2__)
    static_assert(N % 4 == 0);
    for (int x = 0; x < N; x += 4) {
      const __m128 xs = _mm_setr_ps(float(x), float(x + 1), float(x + 2), float(x + 3));
      const __m128 px = _mm_add_ps(_mm_set1_ps(row.x()), _mm_mul_ps(_mm_set1_ps(dx.x()), xs));
      const __m128 py = _mm_add_ps(_mm_set1_ps(row.y()), _mm_mul_ps(_mm_set1_ps(dx.y()), xs));
      const __m128 pz = _mm_add_ps(_mm_set1_ps(row.z()), _mm_mul_ps(_mm_set1_ps(dx.z()), xs));
      const __m128 inv_z = _mm_div_ps(_mm_set1_ps(1.0f), pz);
      const __m128 fs = _mm_set1_ps(f);
      _mm_store_ps(&z[x], pz);
      _mm_store_ps(&u[x], _mm_add_ps(_mm_mul_ps(_mm_mul_ps(fs, px), inv_z), _mm_set1_ps(cx)));
      _mm_store_ps(&v[x], _mm_add_ps(_mm_mul_ps(_mm_mul_ps(fs, py), inv_z), _mm_set1_ps(cy)));
      const __m128 sq = _mm_add_ps(_mm_mul_ps(px, px), _mm_add_ps(_mm_mul_ps(py, py), _mm_mul_ps(pz, pz)));
      _mm_store_ps(&distance[x], _mm_sqrt_ps(sq));
    }
#else
    for (int x = 0; x < N; ++x) {
      const Vec3f p = row + dx * static_cast<float>(x);
      const float inv_z = 1.0f / p.z();
      z[x] = p.z(), u[x] = f * p.x() * inv_z + cx, v[x] = f * p.y() * inv_z + cy, distance[x] = p.norm();
    }
#endif
  }
};

}  // namespace

TsdfVolume::TsdfVolume(const TsdfOptions& options) : options_(options) {
  near_only_ = options.near_points != nullptr;
  if (near_only_ && options.near_voxels_only)
    near_rows_ = std::make_shared<const VoxelRows>(
        VoxelRows::Of(*options.near_points, options.voxel_m, options.near_margin_m + options.voxel_m));
  if (near_only_) MarkNearBlocks(*options.near_points);
  options_.near_points = nullptr;
}

// Every block that a box of half a block round a point, grown by the margin, overlaps: a
// superset of the blocks within the margin, found per distinct half-block cell, not per point.
// Kept as a dense grid over their bounds: BandBlocks asks for every ray step whether a block is
// near and free, and a grid answers without hashing.
void TsdfVolume::MarkNearBlocks(const std::vector<Vec3f>& points) {
  const double block_m = B * options_.voxel_m;
  const double cell_m = block_m / 2;
  std::unordered_set<Key> cells;
  std::vector<Eigen::Vector3i> near;
  for (const Vec3f& p : points) {
    const Eigen::Vector3i c = (p.cast<double>() / cell_m).array().floor().cast<int>();
    if (!cells.insert(KeyOf(c)).second) continue;
    const Vec3 lo = c.cast<double>() * cell_m - Vec3::Constant(options_.near_margin_m);
    const Vec3 hi = lo + Vec3::Constant(cell_m + 2 * options_.near_margin_m);
    const Eigen::Vector3i b0 = BlockOf(lo), b1 = BlockOf(hi);
    for (int z = b0.z(); z <= b1.z(); ++z)
      for (int y = b0.y(); y <= b1.y(); ++y)
        for (int x = b0.x(); x <= b1.x(); ++x) near.emplace_back(x, y, z);
  }
  if (near.empty()) return;
  near_.lo = near_.hi = near.front();
  for (const Eigen::Vector3i& b : near) near_.lo = near_.lo.cwiseMin(b), near_.hi = near_.hi.cwiseMax(b);
  const Eigen::Vector3i dims = near_.hi - near_.lo + Eigen::Vector3i::Ones();
  near_.slot.assign(static_cast<std::size_t>(dims.x()) * dims.y() * dims.z(), Near::kFar);
  // With near_rows_, a block none of whose voxels would be updated meshes nothing: it stays far
  // (not allocated, its pixels not traced).
  for (const Eigen::Vector3i& b : near)
    if (!near_rows_ || near_rows_->RowsOf(b) != 0) near_.slot[near_.Offset(b)] = Near::kFree;
}

template <class Fn>
void TsdfVolume::ForEachNearBlock(bool free_only, Fn&& fn) const {
  const float v = static_cast<float>(options_.voxel_m);
  for (int z = near_.lo.z(); !near_.slot.empty() && z <= near_.hi.z(); ++z)
    for (int y = near_.lo.y(); y <= near_.hi.y(); ++y)
      for (int x = near_.lo.x(); x <= near_.hi.x(); ++x) {
        const Eigen::Vector3i b(x, y, z);
        const Near slot = near_.slot[near_.Offset(b)];
        if (slot == Near::kFar || (free_only && slot != Near::kFree)) continue;
        const Vec3f lo = (b.cast<float>() * B - Vec3f::Constant(0.5f)) * v;
        fn(Aabb{lo, lo + Vec3f::Constant(B * v)});
      }
}

// Block b holds the points that BlockOf rounds into it, [(bB - 0.5) v, (bB + B - 0.5) v) per axis,
// its voxel centres among them: a pixel whose ray misses every such box of a near block can
// neither allocate nor update a voxel.
PixelMask TsdfVolume::NearPixels(const PinholeCamera& camera, const Iso3& T_volume_camera) const {
  PixelMask mask(static_cast<std::size_t>(camera.width) * camera.height, near_only_ ? 0 : 1);
  const Iso3 T_camera_volume = T_volume_camera.inverse();
  ForEachNearBlock(false, [&](const Aabb& box) {
    const PixelRect r = PixelsOfBox(camera, T_camera_volume, box);
    for (int v = r.v0; v < r.v1; ++v)
      std::fill_n(mask.begin() + static_cast<std::ptrdiff_t>(v) * camera.width + r.u0, std::max(0, r.u1 - r.u0), 1);
  });
  return mask;
}

TsdfVolume::DepthWindow TsdfVolume::FreeBlockDepths(const PinholeCamera& camera, const Iso3& T_volume_camera) const {
  const std::size_t pixels = static_cast<std::size_t>(camera.width) * camera.height;
  DepthWindow window{std::vector<float>(pixels, std::numeric_limits<float>::max()), std::vector<float>(pixels, 0.0f)};
  const Iso3 T_camera_volume = T_volume_camera.inverse();
  const Vec3f eye = T_volume_camera.translation().cast<float>();
  constexpr float kSlack = 1e-4f;  // covers float rounding of the box and of the ray's steps (m)
  ForEachNearBlock(true, [&](const Aabb& box) {
    const PixelRect r = PixelsOfBox(camera, T_camera_volume, box);
    const Vec3f out_of_box = (box.min - eye).cwiseMax(eye - box.max).cwiseMax(Vec3f::Zero());
    const Vec3f far_corner = (box.min - eye).cwiseAbs().cwiseMax((box.max - eye).cwiseAbs());
    const float nearest = std::max(0.0f, out_of_box.norm() - kSlack), farthest = far_corner.norm() + kSlack;
    for (int v = r.v0; v < r.v1; ++v)
      for (int u = r.u0; u < r.u1; ++u) {
        const std::size_t pixel = static_cast<std::size_t>(v) * camera.width + u;
        window.nearest[pixel] = std::min(window.nearest[pixel], nearest);
        window.farthest[pixel] = std::max(window.farthest[pixel], farthest);
      }
  });
  return window;
}

std::ptrdiff_t TsdfVolume::NearGrid::Offset(const Eigen::Vector3i& b) const {
  if (slot.empty() || (b.array() < lo.array()).any() || (b.array() > hi.array()).any()) return -1;
  const Eigen::Vector3i d = hi - lo + Eigen::Vector3i::Ones(), r = b - lo;
  return (static_cast<std::ptrdiff_t>(r.z()) * d.y() + r.y()) * d.x() + r.x();
}

bool TsdfVolume::WouldAllocate(const Eigen::Vector3i& b) const {
  if (!near_only_) return !index_.count(KeyOf(b));
  const std::ptrdiff_t at = near_.Offset(b);
  return at >= 0 && near_.slot[at] == Near::kFree;
}

TsdfVolume::Key TsdfVolume::KeyOf(const Eigen::Vector3i& b) {
  const auto k = [](int v) { return static_cast<std::uint64_t>(v + kKeyBias) & 0x1FFFFF; };
  return (k(b.x()) << 42) | (k(b.y()) << 21) | k(b.z());
}

Eigen::Vector3i TsdfVolume::BlockOf(const Vec3& p, double voxel_m) {
  Eigen::Vector3i b;
  for (int a = 0; a < 3; ++a) b[a] = FloorDiv(static_cast<int>(std::lround(p[a] / voxel_m)), B);
  return b;
}

Status TsdfVolume::Integrate(const PinholeCamera& camera, const Iso3& T_volume_camera, const RangeImage& range,
                             const std::vector<float>& incidence) {
  return IntegrateAll(camera, {{T_volume_camera, &range, &incidence}});
}

Status TsdfVolume::Integrate(const PinholeCamera& camera, const Iso3& T_volume_camera, const RangeImage& range,
                             const std::vector<float>& incidence, const std::vector<Eigen::Vector3i>& band) {
  return IntegrateAll(camera, {{T_volume_camera, &range, &incidence, &band}});
}

// Blocks are allocated image by image, as Integrate does (which blocks an image adds depends on
// which are there, not on their voxels). Then each block takes, in order, the images from the
// one that added it on, in one task: the same updates in the same order as one call per image.
Status TsdfVolume::IntegrateAll(const PinholeCamera& camera, const std::vector<Image>& images,
                                const CancelToken* cancel) {
  for (const Image& image : images)
    if (image.incidence->size() != image.range->size())
      return Status::InvalidArgument("TSDF: incidence image size differs from range");
  std::vector<std::size_t> first_image(blocks_.size(), 0);  // per block, the image that allocated it
  std::vector<Iso3> T_camera_volume;
  for (std::size_t a = 0; a < images.size(); ++a) {
    if (Cancelled(cancel)) return Status::Cancelled("TSDF fusion cancelled");
    const Image& image = images[a];
    ARREF_RETURN_IF_ERROR(Allocate(image.band ? *image.band
                                              : BandBlocks(options_, camera, image.T_volume_camera, *image.range, this)));
    first_image.resize(blocks_.size(), a);
    T_camera_volume.push_back(image.T_volume_camera.inverse());
  }
  // A block's images take microseconds: polled per block, a cancel skips the rest.
  tbb::parallel_for(std::size_t{0}, blocks_.size(), [&](std::size_t i) {
    if (Cancelled(cancel)) return;
    for (std::size_t a = first_image[i]; a < images.size(); ++a)
      UpdateBlock(blocks_[i], camera, T_camera_volume[a], *images[a].range, *images[a].incidence);
  });
  if (Cancelled(cancel)) return Status::Cancelled("TSDF fusion cancelled");
  return Status::Ok();
}

// Collected per row in parallel, merged in row order so block order (and the mesh) is
// deterministic.
std::vector<Eigen::Vector3i> TsdfVolume::BandBlocks(const TsdfOptions& options, const PinholeCamera& camera,
                                                    const Iso3& T_volume_camera, const RangeImage& range,
                                                    const TsdfVolume* allocating) {
  const double trunc = options.truncation_m;
  const double block_m = B * options.voxel_m;
  const double step = std::min(0.5 * block_m, trunc);
  const double keep_radius = options.crop_radius_m + 0.87 * block_m;
  std::vector<std::vector<Eigen::Vector3i>> rows(camera.height);
  // Kept to the band round near_points, only steps inside a block not yet allocated can add
  // one: a pixel is stepped only when its steps, [r - trunc, r + trunc] along the ray, reach the
  // depths of such a block on its ray (exact). Unseen blocks behind the robot lie on its own
  // pixels' rays, but deeper than the steps go.
  DepthWindow adding;
  if (allocating && allocating->near_only_) adding = allocating->FreeBlockDepths(camera, T_volume_camera);
  tbb::parallel_for(0, camera.height, [&](int v) {
    Key last = ~Key{0};
    for (int u = 0; u < camera.width; ++u) {
      const std::size_t pixel = static_cast<std::size_t>(v) * camera.width + u;
      const float r = range[pixel];
      if (r <= 0) continue;
      if (!adding.nearest.empty() && (r + trunc < adding.nearest[pixel] || r - trunc > adding.farthest[pixel])) continue;
      const Vec3 dir = T_volume_camera.linear() * camera.RayDirection(u, v);
      for (double t = r - trunc; t <= r + trunc + 1e-9; t += step) {
        const Vec3 p = T_volume_camera.translation() + t * dir;
        if ((p - options.crop_center).norm() > keep_radius) continue;
        const Eigen::Vector3i b = BlockOf(p, options.voxel_m);
        const Key k = KeyOf(b);
        if (k == last) continue;
        last = k;
        if (!allocating || allocating->WouldAllocate(b)) rows[v].push_back(b);
      }
    }
  });
  std::vector<Eigen::Vector3i> band;
  std::unordered_set<Key> listed;
  for (const auto& row : rows)
    for (const Eigen::Vector3i& b : row)
      if (listed.insert(KeyOf(b)).second) band.push_back(b);
  return band;
}

// Allocates the band's blocks that are new (and near, when near_points were given).
Status TsdfVolume::Allocate(const std::vector<Eigen::Vector3i>& band) {
  for (const Eigen::Vector3i& b : band) {
    if (!WouldAllocate(b)) continue;
    if (blocks_.size() >= options_.max_blocks)
      return Status::ResourceExhausted("TSDF fusion needs more than " + std::to_string(options_.max_blocks) +
                                       " voxel blocks: fusion.voxel_m is too small for the scene");
    if (near_only_) near_.slot[near_.Offset(b)] = Near::kAllocated;
    index_.emplace(KeyOf(b), static_cast<int>(blocks_.size()));
    blocks_.push_back(Block{b, std::vector<Voxel>(kVoxelsPerBlock)});
    if (near_rows_) blocks_.back().rows = near_rows_->RowsOf(b);
  }
  return Status::Ok();
}

void TsdfVolume::UpdateBlock(Block& block, const PinholeCamera& camera, const Iso3& T_camera_volume,
                             const RangeImage& range, const std::vector<float>& incidence) const {
  const double v = options_.voxel_m;
  const Vec3 origin = T_camera_volume * (block.index.cast<double>() * (B * v));
  const Eigen::Matrix3d step = T_camera_volume.linear() * v;
  const Vec3 center = origin + step * Vec3::Constant(0.5 * (B - 1));
  if (center.z() < -0.87 * B * v) return;  // wholly behind the camera
  if (options_.single_precision)
    UpdateVoxelsFast(block, camera, origin.cast<float>(), step.cast<float>(), range, incidence);
  else
    UpdateVoxels<double>(block, camera, origin, step, range, incidence);
}

// The voxel update of UpdateVoxels in float with one division per voxel instead of three: the
// projection (PinholeCamera::Project's) multiplies by 1/z, the running mean by 1/(w+1) from a table (weights are whole
// numbers up to kMaxWeight). A block whose corners all project off one side of the image is
// skipped whole. Rounding differs from UpdateVoxels' in the last bits, which is why the
// simulator (which must reproduce its meshes bit for bit) keeps the double update.
void TsdfVolume::UpdateVoxelsFast(Block& block, const PinholeCamera& camera, const Vec3f& origin,
                                  const Eigen::Matrix3f& step, const RangeImage& range,
                                  const std::vector<float>& incidence) const {
  static const std::array<float, static_cast<int>(kMaxWeight) + 1> kInverse = [] {
    std::array<float, static_cast<int>(kMaxWeight) + 1> inv{};
    for (std::size_t w = 0; w < inv.size(); ++w) inv[w] = 1.0f / static_cast<float>(w + 1);
    return inv;
  }();
  if (OffImage(camera, origin, step)) return;
  const float f = static_cast<float>(camera.focal_px), cx = static_cast<float>(camera.cx()),
              cy = static_cast<float>(camera.cy());
  const float width = static_cast<float>(camera.width), height = static_cast<float>(camera.height);
  const float trunc = static_cast<float>(options_.truncation_m), inv_trunc = 1.0f / trunc;
  for (int z = 0; z < B; ++z)
    for (int y = 0; y < B; ++y) {
      if (!(block.rows >> (y + B * z) & 1)) continue;
      const Vec3f row = origin + step.col(1) * static_cast<float>(y) + step.col(2) * static_cast<float>(z);
      // The row's projections and distances, four voxels at a time (RowOfVoxels); the same
      // IEEE operations in the same order as one at a time, so the same bits.
      const RowOfVoxels<B> voxels(row, step.col(0), f, cx, cy);
      for (int x = 0; x < B; ++x) {
        if (voxels.z[x] <= 1e-6f) continue;
        const float u = voxels.u[x], v = voxels.v[x];
        if (!(u >= 0 && v >= 0 && u < width && v < height)) continue;
        const int pixel = static_cast<int>(v) * camera.width + static_cast<int>(u);
        if (range[pixel] <= 0) continue;
        const float sdf = (range[pixel] - voxels.distance[x]) * std::max(0.1f, incidence[pixel]);
        if (sdf < -trunc) continue;
        Voxel& vox = block.voxels[LocalIndex(x, y, z)];
        const float d = std::min(1.0f, sdf * inv_trunc);
        vox.d = (vox.d * vox.w + d) * kInverse[static_cast<int>(vox.w)];
        vox.w = std::min(vox.w + 1.0f, kMaxWeight);
      }
    }
}

// True when every corner of the block is in front of the camera and all project beyond the
// same edge of the image: then no voxel of it projects onto the image.
bool TsdfVolume::OffImage(const PinholeCamera& camera, const Vec3f& origin, const Eigen::Matrix3f& step) {
  std::array<int, 4> beyond = {0, 0, 0, 0};  // left, right, top, bottom
  for (int c = 0; c < 8; ++c) {
    const Vec3f p = origin + step * Vec3f((c & 1) * (B - 1), ((c >> 1) & 1) * (B - 1), ((c >> 2) & 1) * (B - 1));
    if (p.z() <= 1e-6f) return false;
    const Eigen::Vector2f uv = camera.Project(p);
    beyond[0] += uv.x() < 0;
    beyond[1] += uv.x() >= static_cast<float>(camera.width);
    beyond[2] += uv.y() < 0;
    beyond[3] += uv.y() >= static_cast<float>(camera.height);
  }
  return std::any_of(beyond.begin(), beyond.end(), [](int n) { return n == 8; });
}

template <class Scalar>
void TsdfVolume::UpdateVoxels(Block& block, const PinholeCamera& camera, const Eigen::Matrix<Scalar, 3, 1>& origin,
                              const Eigen::Matrix<Scalar, 3, 3>& step, const RangeImage& range,
                              const std::vector<float>& incidence) const {
  using Vec = Eigen::Matrix<Scalar, 3, 1>;
  const auto trunc = static_cast<Scalar>(options_.truncation_m);
  for (int z = 0; z < B; ++z)
    for (int y = 0; y < B; ++y) {
      if (!(block.rows >> (y + B * z) & 1)) continue;
      for (int x = 0; x < B; ++x) {
        const Vec p = origin + step * Vec(x, y, z);
        const int pixel = camera.PixelOf(p);
        if (pixel < 0 || range[pixel] <= 0) continue;
        // Distance along the ray times the incidence cosine: distance to the surface's plane.
        const Scalar sdf = (range[pixel] - p.norm()) * std::max(0.1f, incidence[pixel]);
        if (sdf < -trunc) continue;  // hidden behind the measured surface: no information
        Voxel& vox = block.voxels[LocalIndex(x, y, z)];
        const auto d = static_cast<float>(std::min(Scalar(1), sdf / trunc));
        vox.d = (vox.d * vox.w + d) / (vox.w + 1.0f);
        vox.w = std::min(vox.w + 1.0f, kMaxWeight);
      }
    }
}

std::vector<TsdfVolume::NeighbourTable> TsdfVolume::Neighbours() const {
  std::vector<NeighbourTable> table(blocks_.size());
  for (std::size_t i = 0; i < blocks_.size(); ++i)
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const auto it = index_.find(KeyOf(blocks_[i].index + Eigen::Vector3i(dx, dy, dz)));
          table[i][(dx + 1) + 3 * (dy + 1) + 9 * (dz + 1)] = it == index_.end() ? -1 : it->second;
        }
  return table;
}

const TsdfVolume::Voxel* TsdfVolume::VoxelAt(const NeighbourTable& nb, int x, int y, int z) const {
  const int b = nb[NeighbourSlot(x, y, z)];
  return b < 0 ? nullptr : &blocks_[b].voxels[LocalIndex(x, y, z)];
}

// One vertex per cell (8 voxels) with a sign change, at the mean of its edges' zero crossings.
void TsdfVolume::CellVertices(int block, const NeighbourTable& nb, std::vector<int>& cell_vertex,
                              std::vector<Vec3f>& vertices) const {
  cell_vertex.assign(kVoxelsPerBlock, -1);
  const Eigen::Vector3i base = blocks_[block].index * B;
  const std::vector<Voxel>& own = blocks_[block].voxels;
  for (int z = 0; z < B; ++z)
    for (int y = 0; y < B; ++y)
      for (int x = 0; x < B; ++x) {
        std::array<float, 8> d;
        int negative = 0;
        bool seen = true;
        // A cell wholly inside the block reads its corners there; only the cells on its far faces
        // need the neighbour table.
        const bool inside = x < B - 1 && y < B - 1 && z < B - 1;
        for (int c = 0; c < 8 && seen; ++c) {
          const int cx = x + (c & 1), cy = y + ((c >> 1) & 1), cz = z + ((c >> 2) & 1);
          const Voxel* vox = inside ? &own[LocalIndex(cx, cy, cz)] : VoxelAt(nb, cx, cy, cz);
          seen = vox != nullptr && vox->w > 0;
          if (seen) negative += (d[c] = vox->d) < 0;
        }
        if (!seen || negative == 0 || negative == 8) continue;
        Vec3 sum = Vec3::Zero();
        int crossings = 0;
        for (int c = 0; c < 8; ++c)
          for (int bit : {1, 2, 4}) {
            if ((c & bit) || (d[c] < 0) == (d[c | bit] < 0)) continue;
            const double t = d[c] / (d[c] - d[c | bit]);
            const Vec3 pc((c & 1), (c >> 1) & 1, (c >> 2) & 1);
            const Vec3 axis(bit == 1, bit == 2, bit == 4);
            sum += pc + t * axis;
            ++crossings;
          }
        const Vec3 p = (base + Eigen::Vector3i(x, y, z)).cast<double>() + sum / crossings;
        cell_vertex[LocalIndex(x, y, z)] = static_cast<int>(vertices.size());
        vertices.push_back((p * options_.voxel_m).cast<float>());
      }
}

// A quad per voxel edge with a sign change, joining the vertices of the 4 cells around it.
void TsdfVolume::CellQuads(int block, const NeighbourTable& nb, const std::vector<std::vector<int>>& cell_vertex,
                           const std::vector<std::uint32_t>& first_vertex, const std::vector<Vec3f>& vertices,
                           std::vector<Triangle>& triangles) const {
  // Around an edge along axis a, the cells in the plane of axes u = a+1, v = a+2 (cyclic, so
  // u x v = a) listed counter-clockwise as seen from +a.
  static constexpr int kAround[4][2] = {{-1, -1}, {0, -1}, {0, 0}, {-1, 0}};
  const std::vector<Voxel>& own = blocks_[block].voxels;
  for (int z = 0; z < B; ++z)
    for (int y = 0; y < B; ++y)
      for (int x = 0; x < B; ++x) {
        const Voxel& v0 = own[LocalIndex(x, y, z)];
        if (v0.w <= 0) continue;
        // Away from the block's faces every voxel and cell read lies in the block itself.
        const bool inside = x > 0 && y > 0 && z > 0 && x < B - 1 && y < B - 1 && z < B - 1;
        for (int a = 0; a < 3; ++a) {
          Eigen::Vector3i p1(x, y, z);
          ++p1[a];
          const Voxel* v1 = inside ? &own[LocalIndex(p1.x(), p1.y(), p1.z())] : VoxelAt(nb, p1.x(), p1.y(), p1.z());
          if (v1 == nullptr || v1->w <= 0 || (v0.d < 0) == (v1->d < 0)) continue;
          std::array<std::uint32_t, 4> quad;
          bool complete = true;
          for (int k = 0; k < 4 && complete; ++k) {
            Eigen::Vector3i c(x, y, z);
            c[(a + 1) % 3] += kAround[k][0];
            c[(a + 2) % 3] += kAround[k][1];
            const int b = inside ? block : nb[NeighbourSlot(c.x(), c.y(), c.z())];
            const int id = b < 0 ? -1 : cell_vertex[b][LocalIndex(c.x(), c.y(), c.z())];
            complete = id >= 0;
            if (complete) quad[k] = first_vertex[b] + static_cast<std::uint32_t>(id);
          }
          if (!complete) continue;
          // Solid (negative) below along +a: the surface faces +a, keep the order; else flip.
          if (v0.d >= 0) std::swap(quad[1], quad[3]);
          EmitQuad(quad, vertices, triangles);
        }
      }
}

TriangleMesh TsdfVolume::ExtractMesh() const {
  const auto nb = Neighbours();
  const int n = static_cast<int>(blocks_.size());
  std::vector<std::vector<int>> cell_vertex(n);
  std::vector<std::vector<Vec3f>> block_vertices(n);
  tbb::parallel_for(0, n, [&](int i) { CellVertices(i, nb[i], cell_vertex[i], block_vertices[i]); });

  TriangleMesh mesh;
  std::vector<std::uint32_t> first_vertex(n);
  for (int i = 0; i < n; ++i) {
    first_vertex[i] = static_cast<std::uint32_t>(mesh.vertices.size());
    mesh.vertices.insert(mesh.vertices.end(), block_vertices[i].begin(), block_vertices[i].end());
  }
  std::vector<std::vector<Triangle>> block_triangles(n);
  tbb::parallel_for(0, n, [&](int i) {
    CellQuads(i, nb[i], cell_vertex, first_vertex, mesh.vertices, block_triangles[i]);
  });
  for (const auto& t : block_triangles) mesh.triangles.insert(mesh.triangles.end(), t.begin(), t.end());
  spdlog::debug("sim: surface nets over {} blocks: {} vertices, {} triangles", n, mesh.vertices.size(),
                mesh.triangles.size());
  return mesh;
}

// Each point is taken as the centre of its voxel, the radius grown by half the voxel's diagonal.
// The ball round a voxel is one pattern of rows: row (dy, dz) off it holds the voxels up to
// half_width(dy, dz) from its x. So the points' voxels are marked as bit rows along x (one per
// (y, z) of a block-aligned grid), each marked row is widened once per half width, and ORed into
// the rows the pattern reaches: word operations per marked row, not per voxel or point. Then
// each block's eight bits of a row are read out.
VoxelRows VoxelRows::Of(const std::vector<Vec3f>& points, double voxel_m, double radius_m) {
  static_assert(64 % B == 0, "a block's bits of a row must lie in one word");
  VoxelRows out;
  if (points.empty() || !(voxel_m > 0) || !(radius_m >= 0)) return out;
  const double r = radius_m / voxel_m + 0.5 * std::sqrt(3.0);
  const int reach = static_cast<int>(std::floor(r));
  struct Row {
    int dy, dz, half_width;
  };
  std::vector<Row> ball;
  for (int dz = -reach; dz <= reach; ++dz)
    for (int dy = -reach; dy <= reach; ++dy)
      if (const double left = r * r - dy * dy - dz * dz; left >= 0)
        ball.push_back({dy, dz, static_cast<int>(std::floor(std::sqrt(left)))});
  std::vector<Eigen::Vector3i> voxels(points.size());
  for (std::size_t k = 0; k < points.size(); ++k)
    for (int a = 0; a < 3; ++a) voxels[k][a] = static_cast<int>(std::lround(points[k][a] / voxel_m));
  Eigen::Vector3i lo = voxels.front(), hi = lo;
  for (const Eigen::Vector3i& v : voxels) lo = lo.cwiseMin(v), hi = hi.cwiseMax(v);
  for (int a = 0; a < 3; ++a) {
    out.lo_[a] = FloorDiv(lo[a] - reach, B);
    out.dims_[a] = FloorDiv(hi[a] + reach, B) - out.lo_[a] + 1;
  }
  const Eigen::Vector3i first = out.lo_ * B, size = out.dims_ * B;  // the grid, in voxels
  const std::size_t words = (static_cast<std::size_t>(size.x()) + 63) / 64;
  const auto line = [&](std::vector<std::uint64_t>& bits, int y, int z) {
    return &bits[words * (static_cast<std::size_t>(y) + static_cast<std::size_t>(size.y()) * z)];
  };
  std::vector<std::uint64_t> marked(words * size.y() * size.z(), 0), near(marked.size(), 0);
  std::vector<Eigen::Vector2i> marked_rows;  // (y, z)
  for (const Eigen::Vector3i& v : voxels) {
    const Eigen::Vector3i g = v - first;
    std::uint64_t* row = line(marked, g.y(), g.z());
    if (std::all_of(row, row + words, [](std::uint64_t w) { return w == 0; })) marked_rows.emplace_back(g.y(), g.z());
    row[g.x() / 64] |= std::uint64_t{1} << (g.x() % 64);
  }
  // widened[w]: a marked row with each bit spread w voxels either way (the grid's margin of
  // `reach` voxels keeps every spread bit inside it).
  std::vector<std::vector<std::uint64_t>> widened(static_cast<std::size_t>(reach) + 1, std::vector<std::uint64_t>(words));
  for (const Eigen::Vector2i& m : marked_rows) {
    const std::uint64_t* source = line(marked, m.x(), m.y());
    widened[0].assign(source, source + words);
    for (int w = 1; w <= reach; ++w) {
      const std::vector<std::uint64_t>& a = widened[static_cast<std::size_t>(w) - 1];
      for (std::size_t k = 0; k < words; ++k)
        widened[static_cast<std::size_t>(w)][k] = a[k] | a[k] << 1 | (k > 0 ? a[k - 1] >> 63 : 0) | a[k] >> 1 |
                                                   (k + 1 < words ? a[k + 1] << 63 : 0);
    }
    for (const Row& row : ball) {
      const std::vector<std::uint64_t>& spread = widened[static_cast<std::size_t>(row.half_width)];
      std::uint64_t* target = line(near, m.x() + row.dy, m.y() + row.dz);
      for (std::size_t k = 0; k < words; ++k) target[k] |= spread[k];
    }
  }
  out.rows_.assign(static_cast<std::size_t>(out.dims_.x()) * out.dims_.y() * out.dims_.z(), 0);
  const std::uint64_t block_row = (std::uint64_t{1} << B) - 1;  // a block's B bits of a grid row
  for (int z = 0; z < size.z(); ++z)
    for (int y = 0; y < size.y(); ++y) {
      const std::uint64_t* row = line(near, y, z);
      const std::uint64_t bit = std::uint64_t{1} << (y % B + B * (z % B));
      for (int bx = 0; bx < out.dims_.x(); ++bx)
        if (row[bx * B / 64] >> (bx * B % 64) & block_row) out.rows_[out.Slot({bx, y / B, z / B})] |= bit;
    }
  return out;
}

std::size_t VoxelRows::Slot(const Eigen::Vector3i& d) const {
  return static_cast<std::size_t>(d.x()) +
         static_cast<std::size_t>(dims_.x()) * (d.y() + static_cast<std::size_t>(dims_.y()) * d.z());
}

std::uint64_t VoxelRows::RowsOf(const Eigen::Vector3i& block) const {
  const Eigen::Vector3i d = block - lo_;
  if ((d.array() < 0).any() || (d.array() >= dims_.array()).any()) return 0;
  return rows_[Slot(d)];
}

}  // namespace arref
