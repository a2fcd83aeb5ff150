// The server's YAML config: the shipped default loads, and each bad value is named with its
// key, its text and what it must be (yaml-cpp alone says "bad conversion").
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "server_config.h"

namespace arref::server {
namespace {

TEST(ServerConfig, ShippedDefaultLoadsAndValidates) {
  auto config = LoadDefaultServerConfig();
  ASSERT_TRUE(config.ok()) << config.status().ToString();
  EXPECT_TRUE(ValidateServerConfig(*config).ok());
  EXPECT_EQ(config->port, 7311);
  EXPECT_FALSE(config->robots.empty());
}

TEST(ServerConfig, ValuesAreReadWithTheirTypes) {
  auto config = ParseServerConfig(
      "server: {port: 8000, workers: 3, idle_timeout_s: 2.5}\n"
      "registration: {tracking_error_m: 0.002, tracking_error_deg: 0.5}\n"
      "robots: [{id: kr5, urdf: builtin, default_joints: {joint_a2: -0.5}}]\n", "/tmp");
  ASSERT_TRUE(config.ok()) << config.status().ToString();
  EXPECT_EQ(config->port, 8000);
  EXPECT_EQ(config->workers, 3);
  EXPECT_DOUBLE_EQ(config->idle_timeout_s, 2.5);
  EXPECT_DOUBLE_EQ(config->registration.arref_icp.tracking_error.position_m, 0.002);
  EXPECT_DOUBLE_EQ(config->registration.arref_icp.tracking_error.orientation_deg, 0.5);
  ASSERT_EQ(config->robots.size(), 1u);
  EXPECT_DOUBLE_EQ(config->robots[0].default_joints.at("joint_a2"), -0.5);
}

TEST(ServerConfig, HardeningLimitsAreReadAndChecked) {
  auto config = ParseServerConfig(
      "server: {hello_timeout_s: 2, frame_timeout_s: 7.5}\n"
      "limits: {max_pending_connections: 10, max_connections_per_peer: 3, max_triangles_per_session: 1000,\n"
      "         max_mesh_bytes_per_session: 65536, memory_budget_bytes: 268435456}\n"
      "robots: [{id: kr5, urdf: builtin}]\n", "/tmp");
  ASSERT_TRUE(config.ok()) << config.status().ToString();
  EXPECT_DOUBLE_EQ(config->hello_timeout_s, 2.0);
  EXPECT_DOUBLE_EQ(config->frame_timeout_s, 7.5);
  EXPECT_EQ(config->limits.max_pending_connections, 10u);
  EXPECT_EQ(config->limits.max_connections_per_peer, 3u);
  EXPECT_EQ(config->limits.max_triangles_per_session, 1000u);
  EXPECT_EQ(config->limits.max_mesh_bytes_per_session, 65536u);
  EXPECT_EQ(config->limits.memory_budget_bytes, 268435456u);
  EXPECT_TRUE(ValidateServerConfig(*config).ok());
  config->limits.memory_budget_bytes = 1 << 20;
  EXPECT_NE(ValidateServerConfig(*config).ToString().find("memory_budget_bytes"), std::string::npos);
  config->limits.memory_budget_bytes = 256u << 20;
  config->hello_timeout_s = 0;
  EXPECT_FALSE(ValidateServerConfig(*config).ok());
  // The shipped default fits a 2 GiB unit with room for the fixed part.
  auto shipped = LoadDefaultServerConfig();
  ASSERT_TRUE(shipped.ok()) << shipped.status().ToString();
  EXPECT_LE(shipped->limits.memory_budget_bytes, std::size_t{1} << 30);
}

TEST(ServerConfig, BadValuesAreNamed) {
  struct Case {
    std::string yaml;
    std::string expected;
  };
  const std::vector<Case> cases{
      {"server:\n  port: abc\n", "port: 'abc' is not a whole number in 0..65535"},
      {"server:\n  port: 99999\n", "port: '99999' is not a whole number in 0..65535"},
      {"server:\n  workers: [2]\n", "workers: a list or mapping is not a whole number"},
      {"limits:\n  max_sessions: -1\n", "max_sessions: '-1' is not a whole number >= 0"},
      {"registration:\n  crop_radius_m: wide\n", "crop_radius_m: 'wide' is not a number"},
      {"robots:\n  - id: kr5\n    urdf: builtin\n    default_joints: {joint_a1: up}\n",
       "default_joints.joint_a1: 'up' is not a number"},
      {"servr:\n  port: 1\n", "unknown key 'servr'"},
      {"server: [1, 2\n", "YAML"},
  };
  for (const auto& c : cases) {
    auto config = ParseServerConfig(c.yaml, "/tmp");
    ASSERT_FALSE(config.ok()) << c.yaml;
    EXPECT_NE(config.status().ToString().find(c.expected), std::string::npos) << c.yaml << config.status().ToString();
  }
  auto tracking = ParseServerConfig("registration: {tracking_error_deg: -1}\nrobots: [{id: a, urdf: builtin}]\n", "/tmp");
  ASSERT_TRUE(tracking.ok()) << tracking.status().ToString();
  const Status invalid = ValidateServerConfig(*tracking);
  EXPECT_NE(invalid.ToString().find("tracking_error_deg (-1)"), std::string::npos) << invalid.ToString();
  auto config = ParseServerConfig("server:\n  port: abc\n", "/tmp");
  EXPECT_NE(config.status().ToString().find("line 2, column 9"), std::string::npos) << config.status().ToString();
}

}  // namespace
}  // namespace arref::server
