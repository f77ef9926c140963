// The host's end of the simulated USB cable: a pseudo-terminal that pyserial opens exactly
// like /dev/ttyACM0 (through a stable symlink, as udev gives a real board), or a TCP port
// (socket://). Non-blocking; "connected" means a host has the port open, like USB DTR.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

namespace icgt::sim {

class HostPort {
 public:
  virtual ~HostPort() = default;
  // Bytes the host sent; 0 if none (never blocks).
  [[nodiscard]] virtual std::size_t read_some(uint8_t* out, std::size_t cap) = 0;
  // Bytes accepted towards the host; 0 if the host is not reading (its buffer is full).
  [[nodiscard]] virtual std::size_t write_some(const uint8_t* data, std::size_t len) = 0;
  [[nodiscard]] virtual bool connected() = 0;
  // Simulated unplug: the port disappears (the host's reads fail) until replug().
  virtual void unplug() = 0;
  virtual void replug() = 0;
  // The descriptor that turns readable when the host sends (-1 while none): the simulator
  // sleeps on it, so a request is taken in when it arrives, not at the next loop iteration.
  [[nodiscard]] virtual int readable_fd() const = 0;
  // What the host opens: a device path, or socket://127.0.0.1:PORT.
  [[nodiscard]] virtual std::string url() const = 0;
};

// `symlink_path` empty: a fresh path under /tmp. Returns null and sets error on failure.
std::unique_ptr<HostPort> open_pty_port(const std::string& symlink_path, std::string& error);
// port 0: an ephemeral port.
std::unique_ptr<HostPort> open_tcp_port(uint16_t port, std::string& error);

}  // namespace icgt::sim
