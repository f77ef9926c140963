#include "teensy_board.h"

#include <Arduino.h>
#include <IntervalTimer.h>
#include <Wire.h>

namespace icgt::board::teensy {
namespace {

uint32_t read_micros() { return micros(); }

#if defined(__IMXRT1062__)
// The Teensy 4 startup code enables the DWT cycle counter (micros() itself relies on it).
uint32_t read_cycles() { return ARM_DWT_CYCCNT; }
#endif

// attachInterrupt() and IntervalTimer::begin() take plain function pointers with no context,
// so each object that needs an interrupt owns one slot of a fixed trampoline table.
TeensyEdgeInput* volatile g_edge_owner[TeensyEdgeInput::kMaxAttached] = {};

template <std::size_t I>
void edge_trampoline() {
  TeensyEdgeInput* const owner = g_edge_owner[I];
  if (owner != nullptr) owner->on_interrupt();
}

constexpr void (*kEdgeTrampolines[])() = {&edge_trampoline<0>, &edge_trampoline<1>, &edge_trampoline<2>,
                                          &edge_trampoline<3>};
static_assert(sizeof kEdgeTrampolines / sizeof kEdgeTrampolines[0] == TeensyEdgeInput::kMaxAttached);

IntervalTimer g_timers[TeensyAlarm::kMaxAlarms];
TeensyAlarm* g_alarm_owner[TeensyAlarm::kMaxAlarms] = {};
// Constant-initialised, so TeensyAlarm constructors running during static initialisation
// of another translation unit (main.cpp) can count on it.
std::size_t g_alarms_made = 0;

template <std::size_t I>
void alarm_trampoline() {
  TeensyAlarm* const owner = g_alarm_owner[I];
  if (owner != nullptr) owner->on_interrupt();
}

constexpr void (*kAlarmTrampolines[])() = {&alarm_trampoline<0>, &alarm_trampoline<1>};
static_assert(sizeof kAlarmTrampolines / sizeof kAlarmTrampolines[0] == TeensyAlarm::kMaxAlarms);

}  // namespace

// ---------------------------------------------------------------------------------- clock

void TeensyClock::begin() {
#if defined(__IMXRT1062__)
  // Take the two readings back to back so now_ns() and now_us() share one timeline.
  noInterrupts();
  anchor_cycles_ = cycles_.extend(read_cycles);
  anchor_ns_ = micros_.extend(read_micros) * 1000u;
  interrupts();
#endif
}

uint64_t TeensyClock::now_us() const {
#if defined(__IMXRT1062__)
  // Keeps the cycle counter observed often enough (every 3.5 s) even if nobody calls now_ns().
  (void)cycles_.extend(read_cycles);
#endif
  return micros_.extend(read_micros);
}

#if defined(__IMXRT1062__)
uint64_t TeensyClock::now_ns() const {
  const uint64_t cycles = cycles_.extend(read_cycles) - anchor_cycles_;
  // F_CPU_ACTUAL is read every time: it is what the core itself uses after a clock change.
  const uint32_t cycles_per_us = F_CPU_ACTUAL / 1'000'000u;
  // cycles * 1000 stays below 2^64 for about a year of uptime at 600 MHz.
  return anchor_ns_ + cycles * 1000u / cycles_per_us;
}
#endif

// ------------------------------------------------------------------------------------ I2C

void TeensyI2cBus::begin() {
  wire_.begin();
  wire_.setClock(pins::kI2cClockHz);
  // No bus-timeout call: Stream::setTimeout() only governs readBytes()/parseInt(), which this
  // layer does not use, and both Teensy cores bound their own bus waits internally (a stuck
  // bus ends the transfer with code 4 and a bus recovery), which is the hal's "bounded by
  // the bus timeout".
}

hal::I2cStatus TeensyI2cBus::map_end_transmission(uint8_t code) {
  switch (code) {
    case 0: return hal::I2cStatus::ok;
    case 2: return hal::I2cStatus::nack_address;
    case 3: return hal::I2cStatus::nack_data;
    case 5: return hal::I2cStatus::timeout;
    default: return hal::I2cStatus::bus_error;  // 1 (too long: refused earlier), 4, anything new
  }
}

hal::I2cStatus TeensyI2cBus::transfer(uint8_t addr7, const uint8_t* send, std::size_t send_len, uint8_t* recv,
                                      std::size_t recv_len, hal::I2cJoin join) {
  if (send_len > kMaxTransferBytes || recv_len > kMaxTransferBytes) return hal::I2cStatus::bus_error;

  const bool write_phase = send_len > 0 || recv_len == 0;  // recv_len == 0 too: address probe
  if (write_phase) {
    wire_.beginTransmission(addr7);
    if (send_len > 0) (void)wire_.write(send, send_len);  // fits: checked against the buffer above
    // A write followed by a read keeps the bus (repeated start) unless the part needs a STOP.
    const bool stop = recv_len == 0 || join == hal::I2cJoin::stop;
    const hal::I2cStatus st = map_end_transmission(wire_.endTransmission(static_cast<uint8_t>(stop)));
    if (st != hal::I2cStatus::ok || recv_len == 0) return st;
  }

  const uint8_t got =
      wire_.requestFrom(addr7, static_cast<uint8_t>(recv_len), static_cast<uint8_t>(1));  // 1: STOP after the read
  if (got != recv_len) {
    while (wire_.available() > 0) (void)wire_.read();  // leave nothing for the next transfer
    // Both cores return 0 when the address phase of the read was not acknowledged.
    return got == 0 ? hal::I2cStatus::nack_address : hal::I2cStatus::bus_error;
  }
  for (std::size_t i = 0; i < recv_len; ++i) recv[i] = static_cast<uint8_t>(wire_.read());
  return hal::I2cStatus::ok;
}

// ------------------------------------------------------------------------------ digital out

void TeensyDigitalOut::begin() {
  pinMode(pin_, OUTPUT);
  write(level_);
}

void TeensyDigitalOut::write(bool high) {
  level_ = high;
  digitalWriteFast(pin_, high ? HIGH : LOW);
}

// ------------------------------------------------------------------------------ edge input

void TeensyEdgeInput::begin() { pinMode(pin_, pull_ == pins::InputPull::up ? INPUT_PULLUP : INPUT); }

bool TeensyEdgeInput::attach(Handler handler, void* ctx) {
  // digitalPinToInterrupt() is -1 for a pin that cannot interrupt.
  if (handler == nullptr || digitalPinToInterrupt(pin_) < 0) return false;
  detach();  // re-attaching replaces the handler
  for (std::size_t i = 0; i < kMaxAttached; ++i) {
    if (g_edge_owner[i] != nullptr) continue;
    // Everything the interrupt reads is in place before attachInterrupt() enables it.
    handler_ = handler;
    ctx_ = ctx;
    slot_ = static_cast<int>(i);
    g_edge_owner[i] = this;
    attachInterrupt(digitalPinToInterrupt(pin_), kEdgeTrampolines[i], CHANGE);
    return true;
  }
  return false;  // every trampoline taken
}

void TeensyEdgeInput::detach() {
  if (slot_ < 0) return;
  detachInterrupt(digitalPinToInterrupt(pin_));  // no interrupt after this: safe to clear
  g_edge_owner[slot_] = nullptr;
  slot_ = -1;
  handler_ = nullptr;
  ctx_ = nullptr;
}

bool TeensyEdgeInput::read() const { return digitalReadFast(pin_) != 0; }

void TeensyEdgeInput::on_interrupt() {
  const uint64_t t_us = clock_.now_us();  // first: as close to the edge as software gets
  const bool level_high = digitalReadFast(pin_) != 0;
  const Handler handler = handler_;
  if (handler != nullptr) handler(ctx_, level_high, t_us);
}

// ----------------------------------------------------------------------------------- alarm

TeensyAlarm::TeensyAlarm(const hal::Clock& clock) : clock_(clock) {
  if (g_alarms_made < kMaxAlarms) {
    slot_ = static_cast<int>(g_alarms_made++);
    g_alarm_owner[slot_] = this;
  }
}

TeensyAlarm::~TeensyAlarm() {
  cancel();
  if (slot_ >= 0) g_alarm_owner[slot_] = nullptr;  // the slot is not reused: alarms are static
}

void TeensyAlarm::begin() {
  if (slot_ >= 0) g_timers[slot_].priority(kIrqPriority);
}

void TeensyAlarm::set_handler(Handler handler, void* ctx) {
  handler_ = handler;
  ctx_ = ctx;
}

void TeensyAlarm::arm_at(uint64_t t_us) {
  if (slot_ < 0) {
    start_failures_ = start_failures_ + 1;
    return;
  }
  g_timers[slot_].end();  // the old deadline can no longer fire once this returns
  deadline_us_ = t_us;
  armed_ = true;
  start(clock_.now_us());
}

void TeensyAlarm::cancel() {
  // Not armed means no timer is running (the interrupt ends it first), and static
  // initialisation (the Trigger constructor) may call this before the timers are constructed.
  if (!armed_) return;
  g_timers[slot_].end();
  armed_ = false;
}

void TeensyAlarm::start(uint64_t now_us) {
  uint64_t wait_us = deadline_us_ > now_us ? deadline_us_ - now_us : 0;
  if (wait_us < kMinDelayUs) wait_us = kMinDelayUs;
  if (wait_us > kMaxChunkUs) wait_us = kMaxChunkUs;
  // IntervalTimer is periodic; on_interrupt() ends it at the first expiry.
  if (!g_timers[slot_].begin(kAlarmTrampolines[slot_], static_cast<uint32_t>(wait_us))) {
    start_failures_ = start_failures_ + 1;
  }
}

void TeensyAlarm::on_interrupt() {
  g_timers[slot_].end();
  if (!armed_) return;
  const uint64_t now_us = clock_.now_us();
  if (now_us < deadline_us_) {
    start(now_us);  // one chunk of a long wait, or the timer ran a microsecond short
    return;
  }
  armed_ = false;  // before the handler, which may arm again
  const Handler handler = handler_;
  if (handler != nullptr) handler(ctx_, now_us);
}

// ------------------------------------------------------------------------------ USB serial

std::size_t TeensyUsbSerial::write(const uint8_t* data, std::size_t len) {
  const std::size_t n = len < writable() ? len : writable();
  if (n == 0) return 0;
  const std::size_t written = Serial.write(data, n);
  // Teensy 3 holds a partly filled USB packet for a few milliseconds before sending it; the
  // host's clock-offset estimate (TIME_SYNC_REPLY, stamped when the frame is built) would
  // carry that delay. Ask for the packet to go out now.
  Serial.send_now();
  return written;
}

std::size_t TeensyUsbSerial::writable() const {
  const int n = Serial.availableForWrite();
  return n > 0 ? static_cast<std::size_t>(n) : 0;
}

std::size_t TeensyUsbSerial::read(uint8_t* out, std::size_t cap) {
  const int avail = Serial.available();
  std::size_t n = 0;
  while (n < cap && static_cast<int>(n) < avail) {
    const int c = Serial.read();
    if (c < 0) break;
    out[n++] = static_cast<uint8_t>(c);
  }
  return n;
}

bool TeensyUsbSerial::connected() const { return static_cast<bool>(Serial); }

// ------------------------------------------------------------------------------------- RTC

bool TeensyRtc::get_utc_s(int64_t& utc_s) const {
  const int64_t t = static_cast<int64_t>(Teensy3Clock.get());
  if (t < kMinValidUtcS) return false;
  utc_s = t;
  return true;
}

bool TeensyRtc::set_utc_s(int64_t utc_s) {
  if (utc_s < kMinValidUtcS || utc_s > kMaxUtcS) return false;
  Teensy3Clock.set(static_cast<unsigned long>(utc_s));
  // Read back: a second may tick between the two calls, nothing more.
  const int64_t back = static_cast<int64_t>(Teensy3Clock.get());
  return back >= utc_s && back - utc_s <= 1;
}

}  // namespace icgt::board::teensy
