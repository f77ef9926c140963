// Stops a capture nobody is listening to: once the host has sent no valid frame for the capture's
// host_timeout_ms (START_CAPTURE), the camera stops shooting instead of filling its card for a recorder
// that died or a cable that came out (issue 30). The host is heard through any frame that passes the
// decoder (TIME_SYNC, HOST_RECEIVED, PING, any command): a live recorder sends one every second at least.
//
// Time is a parameter: the application tells it when a frame arrived and asks, each loop, whether the
// silence has lasted the timeout. It says so once per capture.
#pragma once

#include <cstdint>

#include "core/limits.hpp"

namespace icgt::core {

class HostWatchdog {
 public:
  static constexpr uint32_t kMinTimeoutMs = limits::kMinHostTimeoutMs;
  static constexpr uint32_t kMaxTimeoutMs = limits::kMaxHostTimeoutMs;

  // 0 (never) or kMinTimeoutMs .. kMaxTimeoutMs.
  [[nodiscard]] static bool valid(uint32_t timeout_ms) {
    return timeout_ms == 0 || (timeout_ms >= kMinTimeoutMs && timeout_ms <= kMaxTimeoutMs);
  }

  // A valid frame from the host arrived at now_us.
  void heard(uint64_t now_us) {
    heard_t_us_ = now_us;
    heard_any_ = true;
  }
  // A capture started at now_us (by a host frame, so the host was heard then) with this timeout; 0: the
  // watchdog stays quiet for the whole capture.
  void arm(uint32_t timeout_ms, uint64_t now_us) {
    heard(now_us);
    timeout_us_ = uint64_t{timeout_ms} * 1000;
    armed_ = timeout_ms != 0;
  }
  // The capture ended (stopped by the host, or finished): nothing left to stop.
  void disarm() { armed_ = false; }

  // True once, at the first call at which the host has been silent for the timeout or longer while armed
  // (then disarmed): the caller stops the capture.
  [[nodiscard]] bool expired(uint64_t now_us) {
    if (!armed_ || now_us < heard_t_us_ || now_us - heard_t_us_ < timeout_us_) return false;
    armed_ = false;
    return true;
  }

  [[nodiscard]] bool armed() const { return armed_; }
  [[nodiscard]] uint32_t timeout_ms() const { return static_cast<uint32_t>(timeout_us_ / 1000); }
  // When the host was last heard (device clock); 0 and heard_any() false before the first frame.
  [[nodiscard]] uint64_t heard_t_us() const { return heard_t_us_; }
  [[nodiscard]] bool heard_any() const { return heard_any_; }

 private:
  uint64_t heard_t_us_ = 0;
  uint64_t timeout_us_ = 0;
  bool armed_ = false;
  bool heard_any_ = false;
};

}  // namespace icgt::core
