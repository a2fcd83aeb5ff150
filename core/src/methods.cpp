// The registry of registration methods: one line per method.
#include <stdexcept>

#include "arref/registration.h"

namespace arref {

const std::vector<MethodInfo>& Methods() {
  static const std::vector<MethodInfo> kMethods = {
      {Method::kPclIcp, "pcl-icp", "PCL point-to-point ICP from the seed (the paper's method)",
       [](const MethodInput& in) {
         return RegisterPclIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, false);
       }},
      {Method::kPclIcpPlane, "pcl-icp-plane", "PCL point-to-plane ICP from the seed",
       [](const MethodInput& in) {
         return RegisterPclIcp(in.model_base, in.scene_world, in.T_world_seed, in.options.icp, true);
       }},
  };
  return kMethods;
}

const MethodInfo& MethodInfoOf(Method method) {
  for (const auto& m : Methods())
    if (m.method == method) return m;
  throw std::logic_error("registration method missing from the registry");  // a programming error
}

Result<Method> ParseMethod(const std::string& name) {
  for (const auto& m : Methods())
    if (name == m.name) return m.method;
  std::string known;
  for (const auto& n : MethodNames()) known += (known.empty() ? "" : ", ") + n;
  return Status::InvalidArgument("unknown registration method '" + name + "' (available: " + known + ")");
}

const char* MethodName(Method method) { return MethodInfoOf(method).name; }

std::vector<std::string> MethodNames() {
  std::vector<std::string> names;
  for (const auto& m : Methods()) names.emplace_back(m.name);
  return names;
}

}  // namespace arref
