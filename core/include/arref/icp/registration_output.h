// What every registration method returns: the pose, what ran, and its own ranking figures.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "arref/base/geometry.h"

namespace arref {

// arref-icp scores its fit again turned about the base's axis far enough to be a wrong pose
// (100 mm of ADD, either way): how far it turned, and the fit's score less the better turn's.
struct TurnedFit {
  double turn_deg = 0.0;
  double lead = 0.0;
};

// arref-icp fits two models of the robot's surface and keeps one: the other's fit, the chance
// that it, not the kept one, is where the robot stands, and how far the kept model lies off the
// scene (its points' median distance from the scene's tangent planes at the kept fit).
struct OtherSurfaceFit {
  Iso3 T_world_base = Iso3::Identity();
  double chance = 0.5;
  double kept_misfit_m = 0.0;
};

struct RegistrationOutput {
  Iso3 T_world_base = Iso3::Identity();
  int iterations = 0;
  bool converged = false;
  std::vector<std::string> stages;  // which steps ran, e.g. {"pcl-icp"}
  // Methods that rank several candidate poses report the winner's score and its lead over
  // the best distinct runner-up (both as inlier fractions); negative when not applicable.
  double score = -1.0;
  double margin = -1.0;
  int hypotheses = 0;
  // Where the method took the headset to have seen the robot from while it mapped (world frame):
  // the app's head path, or the walk arref-icp chose. Empty: the method does not say.
  std::vector<Vec3> eyes_world;
  // arref-icp fits two models of the robot's surface (the shell it predicts the headset makes,
  // and the exact visible one) and keeps one: the pose the other gave and its chance (when
  // has_other_surface).
  bool has_other_surface = false;
  OtherSurfaceFit other_surface;
  std::optional<TurnedFit> turned;  // arref-icp's; none from the other methods
  std::vector<std::pair<std::string, double>> step_ms;  // the method's own steps, in order (profiling)
};

}  // namespace arref
