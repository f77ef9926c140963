// The device's hal::ByteStream in the simulator: the USB cable between the firmware (running
// in virtual device time) and the host port (real time), with what a real link does to
// bytes: delivery in 1 ms USB frames with jitter, and on command dropped bytes, flipped bits
// and unplugging.
//
// Release times are kept on both time axes so the device sees host bytes exactly when
// they would have arrived, however the simulator's main loop happens to be scheduled.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <random>

#include "device/host_port.hpp"
#include "hal/hal.hpp"

namespace icgt::sim {

// The host's CLOCK_MONOTONIC [ns]: the real-time axis the simulator paces and stamps against.
[[nodiscard]] uint64_t monotonic_now_ns();

// Scenario time, host monotonic time and the device clock (hil_sim/README.md, "Time axes").
struct ClockMap {
  uint64_t t0_monotonic_ns = 0;
  double device_offset_us = 0.0;
  double device_drift_ppm = 0.0;

  [[nodiscard]] double tau_s_at_monotonic(uint64_t mono_ns) const {
    return static_cast<double>(static_cast<int64_t>(mono_ns - t0_monotonic_ns)) * 1e-9;
  }
  [[nodiscard]] uint64_t device_us_at_tau(double tau_s) const {
    const double d = device_offset_us + tau_s * 1e6 * (1.0 + device_drift_ppm * 1e-6);
    return d <= 0.0 ? 0 : static_cast<uint64_t>(d);
  }
  [[nodiscard]] double tau_s_at_device(uint64_t device_us) const {
    return (static_cast<double>(device_us) - device_offset_us) * 1e-6 / (1.0 + device_drift_ppm * 1e-6);
  }
  // Before the origin too (tau < 0: a session holding its scenario clock, hil_sim/README.md).
  [[nodiscard]] uint64_t monotonic_ns_at_device(uint64_t device_us) const {
    const double ns = static_cast<double>(t0_monotonic_ns) + tau_s_at_device(device_us) * 1e9;
    return ns <= 0.0 ? 0 : static_cast<uint64_t>(ns);
  }
};

struct LinkImpairment {
  uint32_t frame_us = 1000;   // USB full-speed frame: IN data waits for the host's next poll
  uint32_t jitter_us = 50;    // host controller / scheduler jitter on top, uniform 0..jitter
  double drop_probability = 0.0;  // per byte
  double flip_probability = 0.0;  // per byte: one random bit inverted
};

struct LinkCounters {
  uint64_t bytes_to_host = 0;
  uint64_t bytes_to_device = 0;
  uint64_t dropped = 0;
  uint64_t flipped = 0;
};

class ImpairedStream final : public hal::ByteStream {
 public:
  static constexpr std::size_t kTxCapacity = 4096;  // the device's USB transmit buffering

  ImpairedStream(HostPort& port, const ClockMap& map, uint64_t seed);
  // A new clock map (the `origin` control command). The USB frame grid keeps its phase: it stays
  // anchored at the first map's origin.
  void set_clock_map(const ClockMap& map) { map_ = map; }
  // The firmware's clock (the simulated board's); must be set before the first call.
  void set_device_clock(const hal::Clock& clock) { clock_ = &clock; }

  // Device side (called by the firmware from inside SimBoard::run_until).
  [[nodiscard]] std::size_t write(const uint8_t* data, std::size_t len) override;
  [[nodiscard]] std::size_t writable() const override;
  [[nodiscard]] std::size_t read(uint8_t* out, std::size_t cap) override;
  [[nodiscard]] bool connected() const override { return connected_; }

  // Real-time side, from the simulator's main loop: moves host bytes in and due device
  // bytes out, and refreshes the connection state.
  void pump(uint64_t now_monotonic_ns);
  // When the next byte for the host is due [monotonic ns]; UINT64_MAX if none is queued.
  [[nodiscard]] uint64_t next_release_ns() const {
    return to_host_.empty() ? UINT64_MAX : to_host_.front().release;
  }

  void set_impairment(const LinkImpairment& impairment) { impairment_ = impairment; }
  [[nodiscard]] const LinkImpairment& impairment() const { return impairment_; }
  void unplug();
  void replug();
  [[nodiscard]] const LinkCounters& counters() const { return counters_; }

 private:
  struct Timed {
    uint64_t release;  // device us (towards the device) or monotonic ns (towards the host)
    uint8_t byte;
  };
  [[nodiscard]] bool corrupt(uint8_t& byte);
  [[nodiscard]] uint64_t jitter_ns();

  HostPort& port_;
  const hal::Clock* clock_ = nullptr;
  ClockMap map_;
  uint64_t frame_anchor_ns_;  // USB frames are counted from here [monotonic ns]
  [[nodiscard]] uint64_t next_frame_ns(uint64_t ns, uint64_t frame_ns) const;
  LinkImpairment impairment_{};
  std::mt19937_64 rng_;
  std::deque<Timed> to_host_;
  std::deque<Timed> to_device_;
  bool connected_ = false;
  bool unplugged_ = false;
  LinkCounters counters_{};
};

}  // namespace icgt::sim
