// Which sessions want the results of which robot (Subscribe messages). Thread-safe: results
// are published from worker threads while sessions subscribe from their strands.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>

namespace arref::server {

class Session;

class SubscriberHub {
 public:
  void Set(const std::string& robot_id, const std::shared_ptr<Session>& session, bool subscribe);
  void RemoveSession(std::uint64_t session_id);
  // Sends the frame to every subscriber of the robot except one session (it got it already).
  void Publish(const std::string& robot_id, const std::shared_ptr<const std::string>& frame,
               std::uint64_t except_session);

 private:
  std::mutex mu_;
  // Weak: a subscription never keeps a closed session alive.
  std::map<std::string, std::map<std::uint64_t, std::weak_ptr<Session>>> subscribers_;
};

}  // namespace arref::server
