// The simulator's control channel: a Unix socket taking one text command per line
// (hil_sim/README.md). Non-blocking; the main loop polls it.
#pragma once

#include <functional>
#include <string>

namespace icgt::sim {

class ControlSocket {
 public:
  // handler returns the reply line ("ok" or "error: ...").
  using Handler = std::function<std::string(const std::string& line)>;

  ControlSocket() = default;
  ControlSocket(const ControlSocket&) = delete;
  ControlSocket& operator=(const ControlSocket&) = delete;
  ~ControlSocket();

  [[nodiscard]] bool open(const std::string& path, std::string& error);
  // Accepts, reads and answers whatever is pending; never blocks.
  void poll(const Handler& handler);

 private:
  std::string path_;
  int listen_ = -1;
  int client_ = -1;
  std::string buffer_;
};

}  // namespace icgt::sim
