#include "teensy_board.h"

#include <Arduino.h>
#include <IntervalTimer.h>
#include <Wire.h>

namespace icgt::board::teensy {
namespace {

uint32_t read_micros() { return micros(); }
uint32_t read_cycles() { return ARM_DWT_CYCCNT; }

#if defined(__IMXRT1062__)
uint32_t cpu_hz() { return F_CPU_ACTUAL; }  // what the core itself uses after a clock change
// The RTC marker in SNVS_LPGPR0..2 (battery-backed general purpose registers).
volatile uint32_t* rtc_marker_words() { return &SNVS_LPGPR0; }
#else
uint32_t cpu_hz() { return F_CPU; }
// The K66 VBAT register file (8 words at 0x4003E000, kept by VBAT with the RTC). kinetis.h
// names none of it; the core uses word 7 for its own flag. The fake core defines the macro.
#ifndef ICGT_VBAT_REGISTER_FILE
#define ICGT_VBAT_REGISTER_FILE (reinterpret_cast<volatile uint32_t*>(0x4003E000u))
#endif
volatile uint32_t* rtc_marker_words() { return ICGT_VBAT_REGISTER_FILE; }
constexpr std::size_t kCoreStaleTimeFlagWord = 7;  // 0x4003E01C, see the TeensyRtc comment
#endif
constexpr std::size_t kMarkerWords = 3;

// attachInterrupt() and IntervalTimer::begin() take plain function pointers with no context,
// so each object that needs an interrupt owns one slot of a fixed trampoline table.
TeensyEdgeInput* volatile g_edge_owner[TeensyEdgeInput::kMaxAttached] = {};

template <std::size_t I>
void edge_trampoline() {
  const uint32_t raw = TeensyClock::raw_cycles();  // first: as close to the edge as software gets
  TeensyEdgeInput* const owner = g_edge_owner[I];
  if (owner != nullptr) owner->on_interrupt(raw);
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
#if !defined(__IMXRT1062__)
  // Teensy 3's start-up leaves the DWT cycle counter off (Teensy 4's turns it on).
  ARM_DEMCR |= ARM_DEMCR_TRCENA;
  ARM_DWT_CTRL |= ARM_DWT_CTRL_CYCCNTENA;
#endif
  cycles_per_us_ = cpu_hz() / 1'000'000u;
  // The two readings back to back, so both timelines share one origin (within the few
  // cycles between them, and micros()' own truncation).
  noInterrupts();
  anchor_cycles_ = cycles_.extend(read_cycles);
  anchor_us_ = micros_.extend(read_micros);
  interrupts();
}

uint64_t TeensyClock::now_us() const {
  // Keeps the cycle counter observed often enough (every quarter period) for stamp_us().
  (void)cycles_.extend(read_cycles);
  return micros_.extend(read_micros);
}

uint32_t TeensyClock::raw_cycles() { return read_cycles(); }

uint64_t TeensyClock::stamp_us(uint32_t raw_cycles) const {
  const uint64_t cycles = cycles_.extend_sample(raw_cycles);
  // An edge stamped just before begin() (not possible: edges attach after it) would be 0.
  if (cycles < anchor_cycles_) return anchor_us_;
  return anchor_us_ + (cycles - anchor_cycles_) / cycles_per_us_;
}

uint64_t TeensyClock::now_ns() const {
  const uint64_t cycles = cycles_.extend(read_cycles) - anchor_cycles_;
  // Split so cycles * 1000 cannot overflow: whole microseconds, then the remainder.
  return anchor_us_ * 1000u + cycles / cycles_per_us_ * 1000u + cycles % cycles_per_us_ * 1000u / cycles_per_us_;
}

// ------------------------------------------------------------------------------------ I2C

void TeensyI2cBus::begin() {
  wire_.begin();
  wire_.setClock(pins::kI2cClockHz);
  // No bus-timeout call: Stream::setTimeout() only governs readBytes()/parseInt(), which this
  // layer does not use, and both Teensy Wire libraries bound their own bus waits internally
  // (a stuck bus ends the transfer with code 4 after about 16 ms and a 9-clock recovery),
  // which is the hal's "bounded by the bus timeout". The loop's I2C budget
  // (core::App::kI2cSharePercent) keeps such 16 ms stalls to a quarter of the loop.
}

hal::I2cStatus TeensyI2cBus::map_end_transmission(uint8_t code) {
  switch (code) {
    case 0: return hal::I2cStatus::ok;
    case 2: return hal::I2cStatus::nack_address;  // Teensy 4: any NACK
#if !defined(__IMXRT1062__)
    case 3: return hal::I2cStatus::nack_data;  // Teensy 3 only
#endif
    case 4: return hal::I2cStatus::timeout;
    default: return hal::I2cStatus::bus_error;  // 1 (too long: refused earlier), 5 (T4 FIFO error), new ones
  }
}

hal::I2cStatus TeensyI2cBus::map_request_from(uint8_t got, int available, std::size_t wanted) {
  if (got == wanted && available >= 0 && static_cast<std::size_t>(available) == wanted) return hal::I2cStatus::ok;
#if defined(__IMXRT1062__)
  // 4 with nothing received: the bus never went idle (wait_idle() failed).
  if (got == 4 && available == 0) return hal::I2cStatus::timeout;
#endif
  // Both cores return 0 when the read's address was not acknowledged (Teensy 3 also on a
  // stuck bus: it cannot be told apart there).
  return got == 0 ? hal::I2cStatus::nack_address : hal::I2cStatus::bus_error;
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
  const hal::I2cStatus st = map_request_from(got, wire_.available(), recv_len);
  if (st != hal::I2cStatus::ok) {
    while (wire_.available() > 0) (void)wire_.read();  // leave nothing for the next transfer
    return st;
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

int TeensyEdgeInput::irq_number() const {
  if (digitalPinToInterrupt(pin_) < 0) return -1;
#if defined(__IMXRT1062__)
  return IRQ_GPIO6789;  // the core runs every pin in fast-GPIO mode, one interrupt for all
#else
  // portConfigRegister(pin) is the pin's PORTx_PCRn; ports A..E are 4 KiB apart from PORTA.
  const auto pcr = reinterpret_cast<uintptr_t>(portConfigRegister(pin_));
  constexpr uintptr_t kPortA = 0x4004'9000u;
  const uintptr_t port = (pcr - kPortA) >> 12;
  if (pcr < kPortA || port > 4) return -1;
  return IRQ_PORTA + static_cast<int>(port);
#endif
}

bool TeensyEdgeInput::attach(Handler handler, void* ctx) {
  // digitalPinToInterrupt() is -1 for a pin that cannot interrupt.
  const int irq = irq_number();
  if (handler == nullptr || irq < 0) return false;
  detach();  // re-attaching replaces the handler
  for (std::size_t i = 0; i < kMaxAttached; ++i) {
    if (g_edge_owner[i] != nullptr) continue;
    // Everything the interrupt reads is in place before attachInterrupt() enables it.
    handler_ = handler;
    ctx_ = ctx;
    slot_ = static_cast<int>(i);
    g_edge_owner[i] = this;
    attachInterrupt(digitalPinToInterrupt(pin_), kEdgeTrampolines[i], CHANGE);
    // Neither core sets a priority for pin interrupts (they stay at 128, level with or below
    // USB). On Teensy 3 this raises the whole port's interrupt (other pins of the port that
    // interrupt share it); on Teensy 4 every pin interrupt shares IRQ_GPIO6789.
    NVIC_SET_PRIORITY(irq, irq::kEdgeInputs);
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

void TeensyEdgeInput::on_interrupt(uint32_t raw_cycles) {
  const bool level_high = digitalReadFast(pin_) != 0;
  const uint64_t t_us = clock_.stamp_us(raw_cycles);
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
  generation_ = generation_ + 1;
  deadline_us_ = t_us;
  armed_ = true;
  start(clock_.now_us());
}

void TeensyAlarm::cancel() {
  // Not armed means no timer is running (the interrupt ends it first), and static
  // initialisation (the Trigger constructor) may call this before the timers are constructed.
  if (!armed_) return;
  g_timers[slot_].end();
  generation_ = generation_ + 1;
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
  if (!armed_) {
    g_timers[slot_].end();  // a late expiry of a cancelled or fired alarm
    return;
  }
  const uint64_t now_us = clock_.now_us();
  if (now_us < deadline_us_) {
    // One chunk of a long wait, or the timer ran a microsecond short. end() + begin(): on
    // Teensy 4 the PIT priority is 255 in between, but nothing is done there.
    g_timers[slot_].end();
    start(now_us);
    return;
  }
  armed_ = false;  // before the handler, which may arm again
  const uint32_t generation = generation_;
  const Handler handler = handler_;
  // The shot first, at this interrupt's priority; end() comes after (see the class comment).
  if (handler != nullptr) handler(ctx_, now_us);
  if (generation_ == generation) g_timers[slot_].end();  // not re-armed: one-shot
}

// ------------------------------------------------------------------------------ USB serial

std::size_t TeensyUsbSerial::write(const uint8_t* data, std::size_t len) {
  const std::size_t n = len < writable() ? len : writable();
  if (n == 0) return 0;
  const std::size_t written = Serial.write(data, n);
  if (written > n) {  // (size_t)-1 from Teensy 3: USB not configured or a packet timeout
    write_errors_ = write_errors_ + 1;
    return 0;
  }
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

namespace {
uint32_t marker_check(uint32_t set_s) { return ~(set_s ^ TeensyRtc::kMarkerMagic); }
}  // namespace

bool TeensyRtc::marker_present() const {
  const volatile uint32_t* w = rtc_marker_words();
  return w[0] == kMarkerMagic && w[2] == marker_check(w[1]);
}

bool TeensyRtc::get_utc_s(int64_t& utc_s) const {
  const int64_t t = static_cast<int64_t>(Teensy3Clock.get());
  if (t < kMinValidUtcS || !marker_present()) return false;
  if (t < static_cast<int64_t>(rtc_marker_words()[1])) return false;  // set back since we set it
  utc_s = t;
  return true;
}

bool TeensyRtc::set_utc_s(int64_t utc_s) {
  if (utc_s < kMinValidUtcS || utc_s > kMaxUtcS) return false;
  volatile uint32_t* w = rtc_marker_words();
  w[0] = 0;  // no marker while the time is being written: a reset in between leaves it unset
  Teensy3Clock.set(static_cast<unsigned long>(utc_s));
  // Read back until the new time shows (Teensy 4: the HP counter resyncs a few 32 kHz cycles
  // after rtc_set() returns). A second may tick meanwhile, nothing more.
  const uint32_t start_us = micros();
  bool ok = false;
  for (;;) {
    const int64_t back = static_cast<int64_t>(Teensy3Clock.get());
    if (back >= utc_s && back - utc_s <= 1) {
      ok = true;
      break;
    }
    if (micros() - start_us >= kReadBackDeadlineUs) break;
  }
  if (!ok) return false;
  w[1] = static_cast<uint32_t>(utc_s);
  w[2] = marker_check(static_cast<uint32_t>(utc_s));
  w[0] = kMarkerMagic;
#if !defined(__IMXRT1062__)
  w[kCoreStaleTimeFlagWord] = 0;  // the core's "RTC holds a stale build time" flag
#endif
  static_assert(kMarkerWords == 3, "magic, set_s, check");
  return true;
}

}  // namespace icgt::board::teensy
