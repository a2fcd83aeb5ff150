#include "robot_registry.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>

#include "arref/pipeline/pipeline.h"

namespace arref::server {
namespace {

std::string CacheKey(const std::string& id, const JointValues& joints, std::size_t samples, std::uint64_t seed,
                     const std::set<std::string>* links) {
  std::string key = fmt::format("{}|{}|{}", id, samples, seed);
  for (const auto& [name, value] : joints) key += fmt::format("|{}={:.9g}", name, value);
  if (links)
    for (const std::string& link : *links) key += "|link:" + link;
  return key;
}

}  // namespace

RobotRegistry::RobotRegistry(std::vector<std::unique_ptr<ServedRobot>> robots, std::size_t cache_entries)
    : robots_(std::move(robots)), cache_entries_(std::max<std::size_t>(cache_entries, 1)) {}

Result<std::unique_ptr<RobotRegistry>> RobotRegistry::Load(const std::vector<RobotConfig>& configs,
                                                           std::size_t cache_entries) {
  std::vector<std::unique_ptr<ServedRobot>> robots;
  for (const auto& c : configs) {
    RobotLoadOptions options;
    options.package_path = c.package_path;
    auto model = RobotModel::Load(c.urdf, options);
    if (!model.ok()) return model.status().WithContext("robot '" + c.id + "' (" + c.urdf + ")");
    auto defaults = model->CompleteJoints(c.default_joints);
    if (!defaults.ok()) return defaults.status().WithContext("robot '" + c.id + "' default_joints");
    auto robot = std::make_unique<ServedRobot>(ServedRobot{c, std::move(*model), std::move(*defaults)});
    spdlog::info("robot '{}': {} from {}, {} actuated joints", c.id, robot->model.name(), c.urdf,
                 robot->model.ActuatedJoints().size());
    robots.push_back(std::move(robot));
  }
  return std::unique_ptr<RobotRegistry>(new RobotRegistry(std::move(robots), cache_entries));
}

const ServedRobot* RobotRegistry::Find(const std::string& id) const {
  for (const auto& r : robots_)
    if (r->config.id == id) return r.get();
  return nullptr;
}

std::string RobotRegistry::Ids() const {
  std::string ids;
  for (const auto& r : robots_) ids += (ids.empty() ? "" : ", ") + r->config.id;
  return ids;
}

Result<JointValues> RobotRegistry::ResolveJoints(const ServedRobot& robot, const JointValues& given) const {
  JointValues joints;
  for (const auto& j : robot.model.ActuatedJoints()) joints[j.name] = robot.default_joints.at(j.name);
  for (const auto& [name, value] : given) joints[name] = value;
  return robot.model.CompleteJoints(joints);
}

Result<RobotRegistry::ModelCloud> RobotRegistry::Model(const ServedRobot& robot, const JointValues& joints,
                                                       std::size_t samples, std::uint64_t seed,
                                                       const std::set<std::string>* links) {
  const std::string key = CacheKey(robot.config.id, joints, samples, seed, links);
  std::promise<Result<ModelCloud>> promise;
  Entry entry;
  {
    std::lock_guard lock(mu_);
    lru_.remove(key);
    lru_.push_front(key);
    if (auto it = cache_.find(key); it != cache_.end()) {
      entry = it->second;
    } else {
      cache_.emplace(key, promise.get_future().share());
      EvictLocked();
    }
  }
  if (entry.valid()) return entry.get();  // may wait for the thread that samples it
  auto side = RobotSide::Create(robot.model, joints, samples, seed, links);
  Result<ModelCloud> result = side.ok() ? Result<ModelCloud>(std::move(*side))
                                        : Result<ModelCloud>(side.status());
  promise.set_value(result);
  if (!result.ok()) {  // do not cache failures: the next request retries
    std::lock_guard lock(mu_);
    cache_.erase(key);
    lru_.remove(key);
  }
  return result;
}

void RobotRegistry::EvictLocked() {
  while (cache_.size() > cache_entries_ && !lru_.empty()) {
    cache_.erase(lru_.back());  // a waiter holds its own shared_future copy, so this is safe
    lru_.pop_back();
  }
}

}  // namespace arref::server
