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

// What a recording carries so that a replay registers as the server did.
TEST(ServerConfig, TlsPathsResolveAgainstTheConfigsFolder) {
  auto config = ParseServerConfig(
      "tls: {certificate_chain: tls/server.pem, private_key: /etc/arref/server.key, client_ca: ca.pem}\n"
      "robots: [{id: kr5, urdf: builtin}]\n", "/etc/arref");
  ASSERT_TRUE(config.ok()) << config.status().ToString();
  EXPECT_TRUE(config->tls.enabled());
  EXPECT_EQ(config->tls.certificate_chain, "/etc/arref/tls/server.pem");
  EXPECT_EQ(config->tls.private_key, "/etc/arref/server.key");
  EXPECT_EQ(config->tls.client_ca, "/etc/arref/ca.pem");
  EXPECT_TRUE(ValidateServerConfig(*config).ok());

  auto typo = ParseServerConfig("tls: {certificate: a.pem}\n", "/tmp");
  ASSERT_FALSE(typo.ok());
  EXPECT_NE(typo.status().message().find("tls: unknown key 'certificate'"), std::string::npos) << typo.status().message();

  auto half = ParseServerConfig("tls: {private_key: k.pem}\nrobots: [{id: kr5, urdf: builtin}]\n", "/tmp");
  ASSERT_TRUE(half.ok());
  EXPECT_NE(ValidateServerConfig(*half).message().find("go together"), std::string::npos);
}

// The one rule: a token, no TLS and an address other than loopback is refused unless allowed.
TEST(ServerConfig, AClearTextTokenOffLoopbackNeedsExplicitConsent) {
  const auto config = [](const std::string& server) {
    auto c = ParseServerConfig("server: {" + server + "}\nrobots: [{id: kr5, urdf: builtin}]\n", "/tmp");
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return *c;
  };
  const Status refused = ValidateServerConfig(config("auth_token: t, address: 0.0.0.0"));
  EXPECT_FALSE(refused.ok());
  EXPECT_NE(refused.message().find("clear text"), std::string::npos) << refused.message();
  EXPECT_NE(refused.message().find("allow_plaintext_token"), std::string::npos) << refused.message();
  EXPECT_FALSE(ValidateServerConfig(config("auth_token: t, address: 192.168.1.20")).ok());
  EXPECT_TRUE(ValidateServerConfig(config("auth_token: t, address: 0.0.0.0, allow_plaintext_token: true")).ok());
  EXPECT_FALSE(ClearTextTokenRisk(config("auth_token: t, address: 0.0.0.0, allow_plaintext_token: true")).empty());
  EXPECT_TRUE(ValidateServerConfig(config("auth_token: t, address: 127.0.0.1")).ok());
  EXPECT_TRUE(ValidateServerConfig(config("auth_token: t, address: '::1'")).ok());
  EXPECT_TRUE(ValidateServerConfig(config("auth_token: '', address: 0.0.0.0")).ok());  // no token, nothing to leak
  EXPECT_TRUE(ClearTextTokenRisk(config("auth_token: '', address: 0.0.0.0")).empty());
}

TEST(ServerConfig, RegistrationYamlReadsBackTheSameSettings) {
  auto config = ParseServerConfig(
      "server: {record_dir: /var/lib/arref/recordings}\n"
      "registration: {method: pcl-icp, crop_radius_m: 1.7, scene_samples: 9000, model_samples: 4000,\n"
      "  icp_max_correspondence_m: 0.07, icp_max_iterations: 80, inlier_threshold_m: 0.015, sample_seed: 9,\n"
      "  model_cache_entries: 5, tracking_error_m: 0.0031, tracking_error_deg: 0.7}\n", "/tmp");
  ASSERT_TRUE(config.ok()) << config.status().ToString();
  EXPECT_EQ(config->record_dir, "/var/lib/arref/recordings");
  auto back = ParseServerConfig(RegistrationYaml(*config), "/tmp");
  ASSERT_TRUE(back.ok()) << back.status().ToString() << "\n" << RegistrationYaml(*config);
  const RegistrationOptions& a = config->registration;
  const RegistrationOptions& b = back->registration;
  EXPECT_STREQ(MethodName(b.method), "pcl-icp");
  EXPECT_EQ(b.crop_radius_m, a.crop_radius_m);
  EXPECT_EQ(b.scene_samples, 9000u);
  EXPECT_EQ(b.model_samples, 4000u);
  EXPECT_EQ(b.icp.max_correspondence_m, a.icp.max_correspondence_m);
  EXPECT_EQ(b.icp.max_iterations, 80);
  EXPECT_EQ(b.inlier_threshold_m, a.inlier_threshold_m);
  EXPECT_EQ(b.sample_seed, 9u);
  EXPECT_EQ(back->model_cache_entries, 5u);
  EXPECT_EQ(b.arref_icp.tracking_error.position_m, a.arref_icp.tracking_error.position_m);
  EXPECT_EQ(b.arref_icp.tracking_error.orientation_deg, a.arref_icp.tracking_error.orientation_deg);
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
