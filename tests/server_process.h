// The real arref-server process on loopback for the end-to-end tests, its config written to a
// temp file and its port read from the "listening on" line it prints.
#pragma once

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace arref::testing {

inline const std::string kServerPath = ARREF_BINARY_DIR "/server/arref-server";

struct ServerSettings {
  int workers = 2;
  int queue_size = 32;
  std::size_t max_sessions = 64;
  std::size_t max_send_queue_bytes = 8u << 20;
  double shutdown_grace_s = 60;
  double idle_timeout_s = 300;
  std::size_t max_map_triangles = 1'000'000;
  std::size_t max_connections_per_peer = 256;  // every test client comes from 127.0.0.1
  std::string server_yaml, limits_yaml;  // more keys of those sections, each line "  key: value\n"
  std::string sections_yaml;             // more top-level sections (e.g. "tls:\n  ...")
};

inline std::string ConfigYaml(const ServerSettings& s) {
  std::ostringstream y;
  y << "server:\n  address: 127.0.0.1\n  port: 0\n  workers: " << s.workers << "\n  queue_size: " << s.queue_size
    << "\n  shutdown_grace_s: " << s.shutdown_grace_s << "\n  idle_timeout_s: " << s.idle_timeout_s << "\n" << s.server_yaml
    << "limits:\n  max_sessions: " << s.max_sessions << "\n  max_send_queue_bytes: " << s.max_send_queue_bytes
    << "\n  max_connections_per_peer: " << s.max_connections_per_peer << "\n  max_map_triangles: " << s.max_map_triangles << "\n" << s.limits_yaml << s.sections_yaml << "robots:\n  - id: kr5\n    urdf: builtin\n";
  return y.str();
}

// The real arref-server process, its port read from its stdout.
class ServerProcess {
 public:
  explicit ServerProcess(const ServerSettings& settings = {}) {
    static int counter = 0;
    const std::string tag = FilePrefix(getpid()) + std::to_string(counter++);
    config_path_ = (std::filesystem::temp_directory_path() / (tag + ".yaml")).string();
    log_path_ = (std::filesystem::temp_directory_path() / (tag + ".log")).string();
    std::ofstream(config_path_) << ConfigYaml(settings);
    Spawn();
  }
  ~ServerProcess() {
    if (pid_ > 0) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
    if (stdout_fd_ >= 0) close(stdout_fd_);
    std::filesystem::remove(config_path_);
    std::filesystem::remove(log_path_);
  }

  // The config and log files of every server `process` started: for a test process that died
  // without running destructors, so that its files do not pile up in the temp dir.
  static void RemoveFilesOf(pid_t process) {
    const std::string prefix = FilePrefix(process);
    std::error_code ignored;
    for (const auto& entry : std::filesystem::directory_iterator(std::filesystem::temp_directory_path(), ignored))
      if (entry.path().filename().string().starts_with(prefix)) std::filesystem::remove(entry.path(), ignored);
  }

  std::uint16_t port() const { return port_; }
  pid_t pid() const { return pid_; }
  bool alive() const { return pid_ > 0 && kill(pid_, 0) == 0; }
  std::string Log() const {
    std::ifstream in(log_path_);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  }
  long RssKb() const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
    for (std::string line; std::getline(in, line);)
      if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
    return -1;
  }
  // Sends the signal and waits (bounded) for the exit status; -1 if it did not exit.
  int SignalAndWait(int signal, double timeout_s) {
    kill(pid_, signal);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (std::chrono::steady_clock::now() < deadline) {
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return -1;
  }

 private:
  static std::string FilePrefix(pid_t process) { return "arref_server_test_" + std::to_string(process) + "_"; }

  // fork + exec rather than posix_spawn, so that the child can ask for SIGKILL when the test
  // process dies (PR_SET_PDEATHSIG): a test that aborts (a sanitizer's halt_on_error, a crash)
  // runs no destructor, and its server would otherwise live on. Between fork and exec the child
  // calls only async-signal-safe functions, everything it needs prepared before the fork.
  void Spawn() {
    int out[2];
    ASSERT_EQ(pipe(out), 0);
    std::vector<std::string> args{kServerPath, "--config", config_path_, "--port", "0", "--address", "127.0.0.1"};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    const pid_t parent = getpid();
    pid_ = fork();
    ASSERT_GE(pid_, 0) << "fork: " << std::strerror(errno);
    if (pid_ == 0) {
      prctl(PR_SET_PDEATHSIG, SIGKILL);
      if (getppid() != parent) _exit(127);  // the test died before prctl took effect
      dup2(out[1], STDOUT_FILENO);
      close(out[0]);
      close(out[1]);
      const int log = open(log_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (log >= 0) dup2(log, STDERR_FILENO);
      execve(kServerPath.c_str(), argv.data(), environ);
      _exit(127);
    }
    close(out[1]);
    stdout_fd_ = out[0];
    ReadPort();
  }

  void ReadPort() {
    const std::regex line_re(R"(listening on 127\.0\.0\.1:(\d+))");
    std::string text;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < deadline) {
      pollfd p{stdout_fd_, POLLIN, 0};
      if (poll(&p, 1, 200) <= 0) continue;
      char buf[256];
      const ssize_t n = read(stdout_fd_, buf, sizeof buf);
      if (n <= 0) break;
      text.append(buf, static_cast<std::size_t>(n));
      std::smatch m;
      if (std::regex_search(text, m, line_re)) {
        port_ = static_cast<std::uint16_t>(std::stoi(m[1]));
        return;
      }
    }
    FAIL() << "arref-server did not print its port; stdout: " << text << "\nlog:\n" << Log();
  }

  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::uint16_t port_ = 0;
  std::string config_path_;
  std::string log_path_;
};

}  // namespace arref::testing
