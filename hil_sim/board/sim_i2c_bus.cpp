#include "sim_i2c_bus.hpp"

namespace icgt::sim {

void SimI2cBus::attach(uint8_t addr7, I2cDeviceModel* model) { slots_[addr7 & 0x7F].model = model; }

void SimI2cBus::detach(uint8_t addr7) { slots_[addr7 & 0x7F].model = nullptr; }

void SimI2cBus::fail_next(uint8_t addr7, std::size_t count, hal::I2cStatus status) {
  Slot& s = slots_[addr7 & 0x7F];
  s.fail_count = count;
  s.fail_status = status;
}

hal::I2cStatus SimI2cBus::transfer(uint8_t addr7, const uint8_t* send, std::size_t send_len, uint8_t* recv,
                                   std::size_t recv_len, hal::I2cJoin join) {
  ++transfers_;
  const uint64_t now = clock_.now_us();
  Slot& s = slots_[addr7 & 0x7F];
  hal::I2cStatus status = hal::I2cStatus::ok;
  if (s.fail_count > 0) {
    --s.fail_count;
    status = s.fail_status;
  } else if (s.model == nullptr) {
    status = hal::I2cStatus::nack_address;
  } else {
    if (send_len > 0 || recv_len == 0) status = s.model->on_write(send, send_len, now);
    if (status == hal::I2cStatus::ok && recv_len > 0) {
      if (send_len > 0) s.model->on_join(join);
      status = s.model->on_read(recv, recv_len, now);
    }
  }
  if (recording_) {
    I2cTransaction t{addr7, {}, recv_len, join, status, {}, now};
    if (send_len > 0) t.written.assign(send, send + send_len);
    if (status == hal::I2cStatus::ok && recv_len > 0) t.read.assign(recv, recv + recv_len);
    log_.push_back(std::move(t));
  }
  return status;
}

}  // namespace icgt::sim
