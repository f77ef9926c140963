// An in-memory hal::ByteStream: the device's end of a link whose other end is a test or
// the simulator. Bounded like a USB endpoint (write() takes only what fits), and it can be
// unplugged.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <vector>

#include "hal/hal.hpp"

namespace icgt::sim {

class MemoryStream final : public hal::ByteStream {
 public:
  explicit MemoryStream(std::size_t tx_capacity = 4096) : tx_capacity_(tx_capacity) {}

  // Device side (hal::ByteStream).
  [[nodiscard]] std::size_t write(const uint8_t* data, std::size_t len) override {
    if (!connected_) return 0;
    const std::size_t n = len < writable() ? len : writable();
    to_host_.insert(to_host_.end(), data, data + n);
    return n;
  }
  [[nodiscard]] std::size_t writable() const override {
    return connected_ && to_host_.size() < tx_capacity_ ? tx_capacity_ - to_host_.size() : 0;
  }
  [[nodiscard]] std::size_t read(uint8_t* out, std::size_t cap) override {
    std::size_t n = 0;
    while (n < cap && !to_device_.empty()) {
      out[n++] = to_device_.front();
      to_device_.pop_front();
    }
    return n;
  }
  [[nodiscard]] bool connected() const override { return connected_; }

  // Host side.
  void host_send(const uint8_t* data, std::size_t len) { to_device_.insert(to_device_.end(), data, data + len); }
  [[nodiscard]] std::vector<uint8_t> host_take() {
    std::vector<uint8_t> out(to_host_.begin(), to_host_.end());
    to_host_.clear();
    return out;
  }
  void set_connected(bool up) {
    connected_ = up;
    if (!up) to_device_.clear();
  }
  // Models a host that stops reading: the device's writes back up once tx_capacity fills.
  void set_tx_capacity(std::size_t bytes) { tx_capacity_ = bytes; }

 private:
  std::size_t tx_capacity_;
  std::deque<uint8_t> to_host_;
  std::deque<uint8_t> to_device_;
  bool connected_ = true;
};

// A battery-backed RTC in memory, optionally unset (lost power) or failing.
class SimRtc final : public hal::Rtc {
 public:
  // utc_s_at_zero: the RTC's reading at device time 0; negative = never set.
  SimRtc(const hal::Clock& clock, int64_t utc_s_at_zero) : clock_(clock), utc_s_at_zero_(utc_s_at_zero) {}
  [[nodiscard]] bool get_utc_s(int64_t& utc_s) const override {
    if (utc_s_at_zero_ < 0) return false;
    utc_s = utc_s_at_zero_ + static_cast<int64_t>((clock_.now_us() - set_at_us_) / 1'000'000u);
    return true;
  }
  // Like the Teensy's RTC, setting restarts the seconds prescaler: the next tick is 1 s later.
  [[nodiscard]] bool set_utc_s(int64_t utc_s) override {
    utc_s_at_zero_ = utc_s;
    set_at_us_ = clock_.now_us();
    return true;
  }

 private:
  const hal::Clock& clock_;
  int64_t utc_s_at_zero_;
  uint64_t set_at_us_ = 0;
};

}  // namespace icgt::sim
