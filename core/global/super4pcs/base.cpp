// Base selection (4PCS, Aiger et al. 2008, Sec. 4 "Selecting the base"; Super4PCS keeps it):
// a wide base is robust to noise, but it must fit inside the overlap, hence width ~ overlap x
// the diameter of P.
#include <cmath>
#include <limits>

#include "super4pcs.h"

namespace arref::super4pcs {
namespace {

// Parameters s, t of the closest points of lines a + s (b - a) and c + t (d - c), and the gap.
bool CrossingOf(const Vec3f& a, const Vec3f& b, const Vec3f& c, const Vec3f& d, float* s, float* t, float* gap) {
  const Vec3f u = b - a, v = d - c, w = a - c;
  const float uu = u.dot(u), uv = u.dot(v), vv = v.dot(v), uw = u.dot(w), vw = v.dot(w);
  const float den = uu * vv - uv * uv;
  if (den < 1e-8f * uu * vv) return false;  // parallel segments: no crossing to index
  *s = (uv * vw - vv * uw) / den;
  *t = (uu * vw - uv * uw) / den;
  *gap = ((a + *s * u) - (c + *t * v)).norm();
  return true;
}

// Orders {p0..p3} as (a, b, c, d) whose segments ab and cd cross inside both; false if none do.
bool PairCrossing(const std::array<Vec3f, 4>& p, double delta, Base* base) {
  static constexpr int kPairings[3][4] = {{0, 1, 2, 3}, {0, 2, 1, 3}, {0, 3, 1, 2}};
  for (const auto& k : kPairings) {
    float s, t, gap;
    const Vec3f &a = p[k[0]], &b = p[k[1]], &c = p[k[2]], &d = p[k[3]];
    if (!CrossingOf(a, b, c, d, &s, &t, &gap) || gap > delta) continue;
    if (s < 0.05f || s > 0.95f || t < 0.05f || t > 0.95f) continue;
    base->points = {a, b, c, d};
    base->r1 = s;
    base->r2 = t;
    base->d1 = (b - a).norm();
    base->d2 = (d - c).norm();
    base->cos_angle = (b - a).normalized().dot((d - c).normalized());
    return true;
  }
  return false;
}

}  // namespace

bool SelectBase(const std::vector<Vec3f>& P, double width, double delta, std::mt19937_64& rng, Base* base, int tries) {
  if (P.size() < 4) return false;
  std::uniform_int_distribution<std::size_t> pick(0, P.size() - 1);
  const float max_side = static_cast<float>(width), min_side = 0.4f * max_side;
  for (int attempt = 0; attempt < tries; ++attempt) {
    // a, b, c: the widest triangle among a few random draws with sides in [min_side, max_side].
    const Vec3f a = P[pick(rng)];
    Vec3f b = a, c = a;
    float best_area = 0;
    for (int k = 0; k < 64; ++k) {
      const Vec3f pb = P[pick(rng)], pc = P[pick(rng)];
      const float ab = (pb - a).norm(), ac = (pc - a).norm(), bc = (pc - pb).norm();
      if (ab < min_side || ab > max_side || ac < min_side || ac > max_side || bc < min_side || bc > max_side) continue;
      const float area = (pb - a).cross(pc - a).norm();
      if (area > best_area) best_area = area, b = pb, c = pc;
    }
    if (best_area <= 0) continue;
    // d: on the plane of abc (within delta), as far from a, b and c as the width allows.
    const Vec3f n = (b - a).cross(c - a).normalized();
    float best_spread = 0;
    Vec3f d = a;
    for (const auto& p : P) {
      if (std::abs(n.dot(p - a)) > delta) continue;
      const float spread = std::min({(p - a).norm(), (p - b).norm(), (p - c).norm()});
      if (spread > best_spread && (p - a).norm() <= max_side) best_spread = spread, d = p;
    }
    if (best_spread < min_side * 0.5f) continue;
    if (PairCrossing({a, b, c, d}, delta, base)) return true;
  }
  return false;
}

}  // namespace arref::super4pcs
