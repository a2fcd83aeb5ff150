// Stands in for open3d_mesher.cpp where CMake found no Open3D: the second mesher says so.
#include "open3d_mesher.h"

namespace arref::sim {
namespace {
Status Missing() {
  return Status::FailedPrecondition(
      "the open3d mesher needs Open3D: arref was built without it (apt-get install libopen3d-dev, then re-run cmake)");
}
}  // namespace

bool Open3dAvailable() { return false; }

Result<std::vector<TriangleMesh>> FuseWithOpen3d(const PinholeCamera&, const std::vector<Iso3>&,
                                                 const std::vector<RangeImage>&, const Open3dFusion&,
                                                 const std::vector<int>&) {
  return Missing();
}

Result<TriangleMesh> DecimateWithOpen3d(const TriangleMesh&, int) { return Missing(); }

}  // namespace arref::sim
