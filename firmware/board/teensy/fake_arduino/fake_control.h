// Test-side controls of the fake Teensyduino API (Arduino.h, Wire.h, IntervalTimer.h in this
// folder). Host-only: used by board_host_check.cpp, never by firmware sources.
//
// What the fake does as the real core does (facts from PaulStoffregen/cores and
// PaulStoffregen/Wire 1.58/1.59; nothing of their code is here):
//  - NVIC: every interrupt starts at 128, SysTick 32, USB 112 (Teensy 3) / 128 (Teensy 4).
//    Interrupt handlers run "inside" their interrupt: execution_priority() is the most
//    urgent current priority of the interrupts running, so a priority changed while a
//    handler runs changes what that handler runs at, as on the NVIC.
//  - IntervalTimer priorities per core (IntervalTimer.h).
//  - Wire return codes per core (see teensy_board.h TeensyI2cBus), and the time a stuck bus
//    costs (16 ms wait for idle).
//  - Serial.write() failures: (size_t)-1 on Teensy 3, 0 on Teensy 4.
//  - RTC: Teensy 4's rtc_set() resyncs the HP counter a few 32 kHz cycles late; VBAT
//    power-up and uploads write the core's times (build time on Teensy 3, 2019-01-01 on
//    Teensy 4).
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
// Every micros() call moves time on by this much (0 by default): for busy-wait loops.
void set_micros_step_us(uint32_t step_us);
#if defined(__IMXRT1062__)
constexpr uint32_t kCpuHz = 600'000'000;  // F_CPU_ACTUAL; the cycle counter runs at it
#else
constexpr uint32_t kCpuHz = 180'000'000;  // F_CPU
#endif
// The cycle counter at the current time, exactly (a 64-bit count; the register is its low 32 bits).
[[nodiscard]] uint64_t cycles();
// Sets the cycle counter's phase against time (cycles = time * MHz + offset), e.g. to put its
// 32-bit wrap anywhere.
void set_cycle_offset(uint64_t offset);

// NVIC.
constexpr int kThreadPriority = 256;  // no interrupt running
[[nodiscard]] uint8_t nvic_priority(int irq);
[[nodiscard]] int execution_priority();
[[nodiscard]] int usb_irq();
[[nodiscard]] int pit_irq(int channel);  // Teensy 4: IRQ_PIT for every channel

// Pins.
[[nodiscard]] int pin_mode(uint8_t pin);  // -1 until pinMode()
[[nodiscard]] bool pin_level(uint8_t pin);
[[nodiscard]] uint32_t pin_writes(uint8_t pin);
// execution_priority() at the pin's last digitalWriteFast().
[[nodiscard]] int pin_write_priority(uint8_t pin);
// Drives an input; runs the attached CHANGE handler inside the pin's interrupt when the level changes.
void set_input(uint8_t pin, bool high);
[[nodiscard]] bool interrupt_attached(uint8_t pin);
[[nodiscard]] int pin_irq(uint8_t pin);
// execution_priority() and time at the last ARM_DWT_CYCCNT read.
[[nodiscard]] int last_cyccnt_read_priority();
[[nodiscard]] uint64_t last_cyccnt_read_cycles();
// Runs fn as an interrupt at irq (a nested interrupt, for tests).
void run_in_irq(int irq, void (*fn)(void*), void* ctx);

// Wire: the next endTransmission() returns end_code; requestFrom() delivers up to
// `deliver` bytes of `data`.
struct WireCall {
  char kind;  // 'w' endTransmission, 'r' requestFrom
  uint8_t address;
  uint8_t count;  // bytes written / requested
  uint8_t send_stop;
};
void wire_script(uint8_t end_code, std::vector<uint8_t> data, std::size_t deliver);
// Faults with each core's real codes; cleared by wire_fault(WireFault::none) or reset().
enum class WireFault : uint8_t {
  none,
  nack_address,  // nobody answers the address
  nack_data,     // the part refuses the first data byte
  stuck_bus,     // SDA held low: the core waits 16 ms for idle, recovers, gives up
  fifo_error,    // Teensy 4 LPI2C FIFO error (Teensy 3: arbitration-style failure, code 4)
};
void wire_fault(WireFault fault);
constexpr uint64_t kStuckBusWaitUs = 16'000;
[[nodiscard]] const std::vector<WireCall>& wire_calls();
[[nodiscard]] uint32_t wire_clock_hz();

// IntervalTimers.
[[nodiscard]] int timers_running();
[[nodiscard]] uint64_t last_timer_period_us();
[[nodiscard]] uint8_t last_timer_priority();  // the IntervalTimer's own priority at its last begin()

// USB serial.
void serial_set_connected(bool up);
void serial_set_room(int bytes);  // availableForWrite()
void serial_fail_writes(bool fail);  // Serial.write() fails as the board's core fails it
void serial_push_rx(const std::vector<uint8_t>& bytes);
[[nodiscard]] std::vector<uint8_t>& serial_tx();
[[nodiscard]] uint32_t serial_send_now_calls();

// RTC seconds (Teensy3Clock) and its battery domain.
void rtc_set_raw(unsigned long s);
[[nodiscard]] unsigned long rtc_raw();
// Teensy 4: rtc_get() shows a new rtc_set() value only this long after it (default 92 us,
// three 32.768 kHz cycles); UINT64_MAX: never. Teensy 3: ignored (TSR reads back at once).
void rtc_set_sync_delay_us(uint64_t delay_us);
// The coin cell was replaced / first applied: battery registers cleared, then the core's
// start-up writes its time (Teensy 3: kBuildTimeS and its stale-time flag; Teensy 4: 2019-01-01).
void rtc_vbat_power_up();
// An upload and reboot: Teensy 3's start-up writes kBuildTimeS again if its stale-time flag is
// set (and clears it); Teensy 4's loader writes loader_time_s if non-zero.
void rtc_upload(unsigned long loader_time_s = 0);
constexpr unsigned long kBuildTimeS = 1'764'000'000;  // "build time" (local time of the build machine)
constexpr unsigned long kTeensy4DefaultS = 1'546'300'800;  // 2019-01-01, teensy4/startup.c

// Everything above back to power-on (time 0, no pins, no timers, port closed, NVIC defaults).
void reset();

}  // namespace fake
