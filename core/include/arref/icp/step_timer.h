// Times a method's own steps inside the pipeline's "register" stage (RegistrationOutput::step_ms).
#pragma once

#include <chrono>

#include "arref/icp/registration_output.h"

namespace arref {

// Appends the time since the last Step (or construction) to out under a step name.
class StepTimer {
 public:
  explicit StepTimer(RegistrationOutput* out) : out_(out) {}
  void Step(const char* name) {
    const auto now = std::chrono::steady_clock::now();
    out_->step_ms.emplace_back(name, std::chrono::duration<double, std::milli>(now - last_).count());
    last_ = now;
  }

 private:
  RegistrationOutput* out_;
  std::chrono::steady_clock::time_point last_ = std::chrono::steady_clock::now();
};

}  // namespace arref
