// Tracing an image row in Embree ray packets (rtcIntersect16): the one place that fills Embree's
// ray layout and its triangle buffers, for the expected surfaces' ray caster (raycaster.cpp) and
// the tracker's model caster (track/model_caster.cpp). Include only where Embree is linked.
#pragma once

#include <embree3/rtcore.h>

#include <algorithm>
#include <cstring>
#include <iterator>

#include "arref/base/geometry.h"

namespace arref {

// The mesh's triangles as one geometry of the scene, built at that quality. Embree keeps copies
// in buffers of its own, so the mesh need not outlive the scene.
inline void AttachTriangles(RTCDevice device, RTCScene scene, const TriangleMesh& mesh, RTCBuildQuality quality) {
  RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                         3 * sizeof(float), mesh.vertices.size()));
  auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                            3 * sizeof(unsigned), mesh.triangles.size()));
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) std::memcpy(vb + 3 * i, mesh.vertices[i].data(), 12);
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) std::memcpy(ib + 3 * i, mesh.triangles[i].data(), 12);
  rtcSetGeometryBuildQuality(geom, quality);
  rtcCommitGeometry(geom);
  rtcAttachGeometry(scene, geom);
  rtcReleaseGeometry(geom);
}

// Up to 16 rays from one origin traced as one Embree packet (TraceRow's).
class RayPacket {
 public:
  static constexpr int kRays = 16;
  explicit RayPacket(double max_range_m) : max_range_(static_cast<float>(max_range_m)) { Clear(); }

  // Lane k traces from origin along the unit direction, from 0 to max_range_m, on the next Trace.
  void Set(int k, const Vec3& origin, const Vec3& direction) {
    valid_[k] = -1;
    rh_.ray.org_x[k] = static_cast<float>(origin.x());
    rh_.ray.org_y[k] = static_cast<float>(origin.y());
    rh_.ray.org_z[k] = static_cast<float>(origin.z());
    rh_.ray.dir_x[k] = static_cast<float>(direction.x());
    rh_.ray.dir_y[k] = static_cast<float>(direction.y());
    rh_.ray.dir_z[k] = static_cast<float>(direction.z());
    rh_.ray.tnear[k] = 0.0f;
    rh_.ray.tfar[k] = max_range_;
    rh_.ray.mask[k] = static_cast<unsigned>(-1);  // Embree skips geometry whose mask bits miss the ray's
    rh_.ray.flags[k] = 0;
    rh_.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
    rh_.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
  }
  // Traces the lanes set since the last Clear (nothing when none was).
  void Trace(RTCScene scene, RTCIntersectContext* context) {
    if (std::any_of(std::begin(valid_), std::end(valid_), [](int v) { return v != 0; }))
      rtcIntersect16(valid_, scene, context, &rh_);
  }
  void Clear() {
    for (int& v : valid_) v = 0;
  }
  bool Hit(int k) const { return valid_[k] && rh_.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID; }
  float Distance(int k) const { return rh_.ray.tfar[k]; }
  unsigned Instance(int k) const { return rh_.hit.instID[0][k]; }  // of a hit through an instance
  Vec3 Normal(int k) const { return Vec3(rh_.hit.Ng_x[k], rh_.hit.Ng_y[k], rh_.hit.Ng_z[k]); }

 private:
  RTCRayHit16 rh_;  // 64-byte aligned by Embree's declaration
  alignas(64) int valid_[kRays];
  float max_range_;
};

// Traces rays begin..end-1 of an image row from origin in packets of RayPacket::kRays: the rays of
// a row are coherent, so a packet walks the BVH once for all of them (docs/engine.md, "Ray
// packets"). direction(i, &dir) sets ray i's unit direction, or returns false for a ray not
// traced; on_hit(i, dir, distance, normal, instance) is called for each ray that hits.
template <class Direction, class OnHit>
void TraceRow(RTCScene scene, const Vec3& origin, double max_range_m, int begin, int end, Direction direction,
              OnHit on_hit) {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RayPacket packet(max_range_m);
  Vec3 dirs[RayPacket::kRays];
  for (int first = begin; first < end; first += RayPacket::kRays) {
    const int lanes = std::min(RayPacket::kRays, end - first);
    packet.Clear();
    for (int k = 0; k < lanes; ++k)
      if (direction(first + k, &dirs[k])) packet.Set(k, origin, dirs[k]);
    packet.Trace(scene, &context);
    for (int k = 0; k < lanes; ++k)
      if (packet.Hit(k)) on_hit(first + k, dirs[k], packet.Distance(k), packet.Normal(k), packet.Instance(k));
  }
}

}  // namespace arref
