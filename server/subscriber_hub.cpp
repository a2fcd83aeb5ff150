#include "subscriber_hub.h"

#include <vector>

#include "session.h"

namespace arref::server {

void SubscriberHub::Set(const std::string& robot_id, const std::shared_ptr<Session>& session, bool subscribe) {
  std::lock_guard lock(mu_);
  if (subscribe)
    subscribers_[robot_id][session->id()] = session;
  else
    subscribers_[robot_id].erase(session->id());
}

void SubscriberHub::RemoveSession(std::uint64_t session_id) {
  std::lock_guard lock(mu_);
  for (auto& [robot, sessions] : subscribers_) sessions.erase(session_id);
}

void SubscriberHub::Publish(const std::string& robot_id, const std::shared_ptr<const std::string>& frame,
                            std::uint64_t except_session) {
  std::vector<std::shared_ptr<Session>> targets;
  {
    // Sending happens outside the lock: SendFrame posts to the session's strand.
    std::lock_guard lock(mu_);
    auto it = subscribers_.find(robot_id);
    if (it == subscribers_.end()) return;
    for (const auto& [id, weak] : it->second)
      if (id != except_session)
        if (auto s = weak.lock()) targets.push_back(std::move(s));
  }
  for (auto& s : targets) s->SendFrame(frame);
}

}  // namespace arref::server
