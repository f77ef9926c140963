// A simulated I2C bus: routes each transfer to the register model at its address, records
// every transaction (so tests can compare against a vendor library's exact sequence) and
// fails transfers on command (the SITL habit: simulators are strict and can fail).
//
// Timing: a transfer takes the time its bits need at the bus clock plus a per-call overhead,
// plus any clock stretching by the part, and blocks its caller for that long, as Wire does.
// The bus asks its time passer (SimBoard: run the interrupts due meanwhile, then move the
// clock) to move time to the transfer's end; without one, transfers take no time. Faults on
// command, with the Teensy Wire libraries' behaviour (teensy_board.h): a stuck bus (a part
// holding SDA low) makes every transfer wait stuck_timeout_us and fail with timeout; a part
// stretching SCL past stretch_limit_us fails its transfer with timeout at the limit.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "hal/hal.hpp"

namespace icgt::sim {

// A device on the simulated bus. Models are register files with timing: they see every
// write burst and every read burst with the bus time, and answer as the silicon would.
class I2cDeviceModel {
 public:
  virtual ~I2cDeviceModel() = default;
  // A write burst (len == 0: address-only probe). Returning anything but ok NACKs it.
  [[nodiscard]] virtual hal::I2cStatus on_write(const uint8_t* data, std::size_t len, uint64_t now_us) = 0;
  // A read burst of len bytes from the current register pointer.
  [[nodiscard]] virtual hal::I2cStatus on_read(uint8_t* out, std::size_t len, uint64_t now_us) = 0;
  // Told whether the read that follows a write was joined by a STOP or a repeated start.
  virtual void on_join(hal::I2cJoin /*join*/) {}
};

struct I2cTiming {
  uint32_t clock_hz = 400'000;
  // Per Wire call (endTransmission / requestFrom): the library's register setup and the
  // bus turnaround. A model figure, not measured on a board.
  uint32_t per_call_overhead_us = 10;
  // Teensy 3 gives up on a byte stretched over 5 ms (Teensy 4: 15 ms pin-low); the smaller.
  uint32_t stretch_limit_us = 5'000;
  // Both cores wait 16 ms for the bus to go idle, try a recovery, and return 4.
  uint32_t stuck_timeout_us = 16'000;
};

struct I2cTransaction {
  uint8_t addr7;
  std::vector<uint8_t> written;
  std::size_t read_len;
  hal::I2cJoin join;
  hal::I2cStatus status;
  std::vector<uint8_t> read;  // bytes returned (empty unless ok)
  uint64_t t_us;
};

class SimI2cBus final : public hal::I2cBus {
 public:
  explicit SimI2cBus(const hal::Clock& clock) : clock_(clock) {}

  // Attaches a model at addr7 (replacing any). The model must outlive the bus.
  void attach(uint8_t addr7, I2cDeviceModel* model);
  void detach(uint8_t addr7);

  // The next `count` transfers to addr7 fail with `status` (the part NACKs / the bus hangs).
  void fail_next(uint8_t addr7, std::size_t count, hal::I2cStatus status = hal::I2cStatus::nack_address);

  [[nodiscard]] hal::I2cStatus transfer(uint8_t addr7, const uint8_t* send, std::size_t send_len, uint8_t* recv,
                                        std::size_t recv_len, hal::I2cJoin join = hal::I2cJoin::repeated_start) override;

  // Transaction recording (off by default; a simulator running for hours must not grow).
  void set_recording(bool on) { recording_ = on; }
  [[nodiscard]] const std::vector<I2cTransaction>& transactions() const { return log_; }
  void clear_transactions() { log_.clear(); }
  [[nodiscard]] uint64_t transfer_count() const { return transfers_; }

  // Timing (see the header comment).
  void set_timing(const I2cTiming& timing) { timing_ = timing; }
  [[nodiscard]] const I2cTiming& timing() const { return timing_; }
  void set_time_passer(std::function<void(uint64_t until_us)> passer) { passer_ = std::move(passer); }
  // Fault: SDA held low (every transfer times out) until cleared.
  void set_stuck(bool stuck) { stuck_ = stuck; }
  [[nodiscard]] bool stuck() const { return stuck_; }
  // The part at addr7 holds SCL this long in every transfer it acknowledges (0: never).
  void set_clock_stretch(uint8_t addr7, uint32_t us) { slots_[addr7 & 0x7F].stretch_us = us; }
  // Total time transfers held their callers [us], and the time a transfer would take.
  [[nodiscard]] uint64_t busy_us() const { return busy_us_; }
  [[nodiscard]] uint64_t wire_time_us(std::size_t send_len, std::size_t recv_len, bool write_phase) const;

 private:
  struct Slot {
    I2cDeviceModel* model = nullptr;
    std::size_t fail_count = 0;
    hal::I2cStatus fail_status = hal::I2cStatus::nack_address;
    uint32_t stretch_us = 0;
  };
  const hal::Clock& clock_;
  I2cTiming timing_{};
  std::function<void(uint64_t)> passer_;
  bool stuck_ = false;
  uint64_t busy_us_ = 0;
  Slot slots_[128];
  bool recording_ = false;
  std::vector<I2cTransaction> log_;
  uint64_t transfers_ = 0;
};

}  // namespace icgt::sim
