// A device clock that only moves when told to: exact, repeatable time for unit tests and
// for the simulator's lock-step mode.
#pragma once

#include <cstdint>

#include "hal/hal.hpp"

namespace icgt::sim {

class VirtualClock final : public hal::Clock {
 public:
  explicit VirtualClock(uint64_t start_us = 0) : now_us_(start_us) {}
  [[nodiscard]] uint64_t now_us() const override { return now_us_; }
  void advance_us(uint64_t dt_us) { now_us_ += dt_us; }
  // Moves to t_us; never backwards (the device clock is monotonic).
  void set_us(uint64_t t_us) {
    if (t_us > now_us_) now_us_ = t_us;
  }

 private:
  uint64_t now_us_;
};

}  // namespace icgt::sim
