#include "sim_i2c_bus.hpp"

namespace icgt::sim {

void SimI2cBus::attach(uint8_t addr7, I2cDeviceModel* model) { slots_[addr7 & 0x7F].model = model; }

void SimI2cBus::detach(uint8_t addr7) { slots_[addr7 & 0x7F].model = nullptr; }

void SimI2cBus::fail_next(uint8_t addr7, std::size_t count, hal::I2cStatus status) {
  Slot& s = slots_[addr7 & 0x7F];
  s.fail_count = count;
  s.fail_status = status;
}

uint64_t SimI2cBus::wire_time_us(std::size_t send_len, std::size_t recv_len, bool write_phase) const {
  // 9 bits per byte (8 + ACK), address bytes included, START and STOP one bit time each.
  uint64_t bits = 0;
  uint32_t calls = 0;
  if (write_phase) {
    bits += 9 * (1 + send_len) + 2;
    ++calls;
  }
  if (recv_len > 0) {
    bits += 9 * (1 + recv_len) + 2;
    ++calls;
  }
  return (bits * 1'000'000 + timing_.clock_hz - 1) / timing_.clock_hz + uint64_t{calls} * timing_.per_call_overhead_us;
}

hal::I2cStatus SimI2cBus::transfer(uint8_t addr7, const uint8_t* send, std::size_t send_len, uint8_t* recv,
                                   std::size_t recv_len, hal::I2cJoin join) {
  ++transfers_;
  const uint64_t now = clock_.now_us();
  Slot& s = slots_[addr7 & 0x7F];
  hal::I2cStatus status = hal::I2cStatus::ok;
  const bool write_phase = send_len > 0 || recv_len == 0;
  uint64_t took_us = 0;
  if (stuck_) {
    status = hal::I2cStatus::timeout;
    took_us = timing_.stuck_timeout_us;
  } else if (s.fail_count > 0) {
    --s.fail_count;
    status = s.fail_status;
    took_us = wire_time_us(0, 0, true);
  } else if (s.model == nullptr) {
    status = hal::I2cStatus::nack_address;
    took_us = wire_time_us(0, 0, true);  // the address byte, NACKed, then STOP
  } else if (s.stretch_us > timing_.stretch_limit_us) {
    status = hal::I2cStatus::timeout;  // the library gives up on the stretched byte
    took_us = wire_time_us(0, 0, true) + timing_.stretch_limit_us;
  } else {
    if (write_phase) status = s.model->on_write(send, send_len, now);
    if (status == hal::I2cStatus::ok && recv_len > 0) {
      if (send_len > 0) s.model->on_join(join);
      status = s.model->on_read(recv, recv_len, now);
    }
    took_us = status == hal::I2cStatus::ok ? wire_time_us(send_len, recv_len, write_phase) + s.stretch_us
                                           : wire_time_us(0, 0, true);
  }
  busy_us_ += took_us;
  if (recording_) {
    I2cTransaction t{addr7, {}, recv_len, join, status, {}, now};
    if (send_len > 0) t.written.assign(send, send + send_len);
    if (status == hal::I2cStatus::ok && recv_len > 0) t.read.assign(recv, recv + recv_len);
    log_.push_back(std::move(t));
  }
  if (passer_) passer_(now + took_us);
  return status;
}

}  // namespace icgt::sim
