// A simulated I2C bus: routes each transfer to the register model at its address, records
// every transaction (so tests can compare against a vendor library's exact sequence) and
// fails transfers on command (the SITL habit: simulators are strict and can fail).
#pragma once

#include <cstddef>
#include <cstdint>
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

 private:
  struct Slot {
    I2cDeviceModel* model = nullptr;
    std::size_t fail_count = 0;
    hal::I2cStatus fail_status = hal::I2cStatus::nack_address;
  };
  const hal::Clock& clock_;
  Slot slots_[128];
  bool recording_ = false;
  std::vector<I2cTransaction> log_;
  uint64_t transfers_ = 0;
};

}  // namespace icgt::sim
