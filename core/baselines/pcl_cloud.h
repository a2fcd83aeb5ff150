// Our point clouds as PCL's PointNormal clouds, for the PCL-based global methods and baselines
// (private to arref_baselines). Normals are made unit length (PCL's descriptors assume it); a
// cloud without normals gets +z.
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "arref/base/geometry.h"

namespace arref {

inline pcl::PointCloud<pcl::PointNormal>::Ptr ToPclUnitNormals(const PointCloud& cloud) {
  auto out = pcl::make_shared<pcl::PointCloud<pcl::PointNormal>>();
  out->resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    (*out)[i].getVector3fMap() = cloud.points[i];
    (*out)[i].getNormalVector3fMap() = cloud.has_normals() ? cloud.normals[i].normalized() : Vec3f::UnitZ();
  }
  return out;
}

}  // namespace arref
