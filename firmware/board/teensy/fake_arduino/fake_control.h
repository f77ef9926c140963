// Test-side controls of the fake Teensyduino API (Arduino.h, Wire.h, IntervalTimer.h in this
// folder). Host-only: used by board_host_check.cpp, never by firmware sources.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace fake {

// Time: one 64-bit microsecond count; micros() is its low 32 bits, as on the Teensy.
void set_time_us(uint64_t t_us);
[[nodiscard]] uint64_t time_us();
// Moves time on, running every IntervalTimer expiry on the way in time order.
void advance_us(uint64_t d_us);
constexpr uint32_t kCpuHz = 600'000'000;  // F_CPU_ACTUAL; the cycle counter runs at it

// Pins.
[[nodiscard]] int pin_mode(uint8_t pin);  // -1 until pinMode()
[[nodiscard]] bool pin_level(uint8_t pin);
[[nodiscard]] uint32_t pin_writes(uint8_t pin);
// Drives an input; runs the attached CHANGE handler when the level changes.
void set_input(uint8_t pin, bool high);
[[nodiscard]] bool interrupt_attached(uint8_t pin);

// Wire: the next endTransmission() returns end_code; requestFrom() delivers up to
// `deliver` bytes of `data`.
struct WireCall {
  char kind;  // 'w' endTransmission, 'r' requestFrom
  uint8_t address;
  uint8_t count;  // bytes written / requested
  uint8_t send_stop;
};
void wire_script(uint8_t end_code, std::vector<uint8_t> data, std::size_t deliver);
[[nodiscard]] const std::vector<WireCall>& wire_calls();
[[nodiscard]] uint32_t wire_clock_hz();

// IntervalTimers.
[[nodiscard]] int timers_running();
[[nodiscard]] uint64_t last_timer_period_us();
[[nodiscard]] uint8_t last_timer_priority();

// USB serial.
void serial_set_connected(bool up);
void serial_set_room(int bytes);  // availableForWrite()
void serial_push_rx(const std::vector<uint8_t>& bytes);
[[nodiscard]] std::vector<uint8_t>& serial_tx();
[[nodiscard]] uint32_t serial_send_now_calls();

// RTC seconds (Teensy3Clock).
void rtc_set_raw(unsigned long s);

// Everything above back to power-on (time 0, no pins, no timers, port closed).
void reset();

}  // namespace fake
