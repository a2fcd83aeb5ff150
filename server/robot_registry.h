// The robots a server registers, loaded once at start-up, and a thread-safe cache of their
// model sides (pipeline.h: samples and expected headset surfaces; one per robot + joint state
// + sample count + seed).
#pragma once

#include <cstdint>
#include <future>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "arref/base/geometry.h"
#include "arref/pipeline/pipeline.h"
#include "arref/robot/robot_model.h"
#include "arref/base/status.h"
#include "server_config.h"

namespace arref::server {

struct ServedRobot {
  RobotConfig config;
  RobotModel model;
  JointValues default_joints;  // complete
};

class RobotRegistry {
 public:
  static Result<std::unique_ptr<RobotRegistry>> Load(const std::vector<RobotConfig>& robots,
                                                     std::size_t cache_entries);

  const ServedRobot* Find(const std::string& id) const;
  const std::vector<std::unique_ptr<ServedRobot>>& robots() const { return robots_; }
  std::string Ids() const;  // "kr5, ur5" for error messages

  // The robot's defaults overridden by the given values, completed and validated.
  Result<JointValues> ResolveJoints(const ServedRobot& robot, const JointValues& given) const;

  using ModelCloud = std::shared_ptr<const RobotSide>;
  // Sampled once per key; concurrent callers with the same key wait for the first.
  // links: only these links' geometry (ChooseMovingFit); null: every link.
  Result<ModelCloud> Model(const ServedRobot& robot, const JointValues& joints, std::size_t samples,
                           std::uint64_t seed, const std::set<std::string>* links = nullptr);

 private:
  using Entry = std::shared_future<Result<ModelCloud>>;
  RobotRegistry(std::vector<std::unique_ptr<ServedRobot>> robots, std::size_t cache_entries);
  void EvictLocked();

  std::vector<std::unique_ptr<ServedRobot>> robots_;
  std::size_t cache_entries_;
  mutable std::mutex mu_;
  std::map<std::string, Entry> cache_;
  std::list<std::string> lru_;  // front: most recently used
};

}  // namespace arref::server
