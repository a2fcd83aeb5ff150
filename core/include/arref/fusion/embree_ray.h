// One Embree ray-hit record, ready for rtcIntersect1: the one place that fills Embree's ray
// layout, for the expected surfaces' ray caster (raycaster.cpp) and the tracker's model caster
// (track/model_caster.cpp). Include only where Embree is linked.
#pragma once

#include <embree3/rtcore.h>

#include "arref/base/geometry.h"

namespace arref {

// A ray from `origin` along the unit `direction`, hitting nothing yet, out to max_range_m.
inline RTCRayHit EmbreeRay(const Vec3& origin, const Vec3& direction, double max_range_m) {
  RTCRayHit rh{};
  rh.ray.org_x = static_cast<float>(origin.x());
  rh.ray.org_y = static_cast<float>(origin.y());
  rh.ray.org_z = static_cast<float>(origin.z());
  rh.ray.dir_x = static_cast<float>(direction.x());
  rh.ray.dir_y = static_cast<float>(direction.y());
  rh.ray.dir_z = static_cast<float>(direction.z());
  rh.ray.tnear = 0.0f;
  rh.ray.tfar = static_cast<float>(max_range_m);
  rh.ray.mask = static_cast<unsigned>(-1);  // Embree skips geometry whose mask bits miss the ray's
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  return rh;
}

}  // namespace arref
