// The Teensy board layer: the hal interfaces implemented with documented Teensyduino APIs
// (micros(), Wire, digitalWriteFast/digitalReadFast, attachInterrupt, IntervalTimer, the USB
// Serial object, Teensy3Clock). This header and teensy_board.cpp are the only firmware
// sources besides src/main.cpp that may touch Arduino; this header itself includes none, so
// main.cpp decides what reaches the rest of the program.
//
// Targets: Teensy 3.6 (__MK66FX1M0__, Cortex-M4) and Teensy 4.1 (__IMXRT1062__, Cortex-M7).
// Contracts are the ones in hal/hal.hpp; only what the Teensy adds is written here.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>

#include "hal/hal.hpp"
#include "pins.h"

class TwoWire;  // Wire.h; both Teensy cores name the class TwoWire

namespace icgt::board::teensy {

// Extends a free-running 32-bit counter to 64 bits, lock-free, callable from the loop and
// from any interrupt (nested or not).
//
// state_ packs the wrap count (upper 31 bits) and the counter's top bit at the last
// observation (bit 0). A reader loads state_ BEFORE reading the counter, so the state it
// holds is never newer than its sample; a top bit that went 1 -> 0 since then is one wrap.
// The new state is published with a compare-exchange, so a reader that was preempted by a
// newer observation never moves the state backwards.
// Requirement: the counter is observed at least once per half period (2^31 ticks: 35 min of
// micros(), 3.5 s of a 600 MHz cycle counter). The main loop reads the clock many times per
// millisecond, so only a loop stalled for that long could lose a wrap.
class WrapExtender {
 public:
  template <class ReadCounter>
  [[nodiscard]] uint64_t extend(ReadCounter read_counter) {
    uint32_t seen = state_.load(std::memory_order_acquire);
    const uint32_t raw = read_counter();
    uint32_t wraps = seen >> 1;
    const uint32_t top = raw >> 31;
    if ((seen & 1u) != 0 && top == 0) ++wraps;
    const uint32_t next = (wraps << 1) | top;
    if (next != seen) {
      // Failure means a newer observation got there first; ours adds nothing.
      (void)state_.compare_exchange_strong(seen, next, std::memory_order_acq_rel, std::memory_order_acquire);
    }
    return (uint64_t{wraps} << 32) | raw;
  }

 private:
  std::atomic<uint32_t> state_{0};
};

// Microseconds since boot from micros(), extended to 64 bits. On Teensy 4 it also keeps the
// ARM cycle counter (ARM_DWT_CYCCNT) extended, for now_ns().
class TeensyClock final : public hal::Clock {
 public:
  // Once, in setup(), before anything reads now_ns().
  void begin();
  [[nodiscard]] uint64_t now_us() const override;
#if defined(__IMXRT1062__)
  // Nanoseconds on the now_us() timeline, from the cycle counter (1.67 ns steps at 600 MHz).
  // Board-only: hal::Clock is microseconds, so the core never sees this resolution.
  [[nodiscard]] uint64_t now_ns() const;
#endif

 private:
  mutable WrapExtender micros_;
#if defined(__IMXRT1062__)
  mutable WrapExtender cycles_;
  uint64_t anchor_ns_ = 0;
  uint64_t anchor_cycles_ = 0;
#endif
};

// Wire (I2C0) as hal::I2cBus.
class TeensyI2cBus final : public hal::I2cBus {
 public:
  // Wire's transmit and receive buffers: 32 bytes on Teensy 3 (the smaller of the two cores).
  // Longer transfers are refused instead of being silently truncated by the core.
  static constexpr std::size_t kMaxTransferBytes = 32;

  explicit TeensyI2cBus(TwoWire& wire) : wire_(wire) {}
  // Wire.begin() and the bus clock (pins::kI2cClockHz).
  void begin();
  [[nodiscard]] hal::I2cStatus transfer(uint8_t addr7, const uint8_t* send, std::size_t send_len, uint8_t* recv,
                                        std::size_t recv_len, hal::I2cJoin join) override;

  // Wire.endTransmission() result codes as the hal sees them (Arduino's documented codes:
  // 0 ok, 1 data too long, 2 NACK on address, 3 NACK on data, 4 other error, 5 timeout).
  [[nodiscard]] static hal::I2cStatus map_end_transmission(uint8_t code);

 private:
  TwoWire& wire_;
};

class TeensyDigitalOut final : public hal::DigitalOut {
 public:
  explicit TeensyDigitalOut(uint8_t pin) : pin_(pin) {}
  // Makes the pin an output driving the last level written. The App constructor (static
  // initialisation, before setup()) already wrote the inactive level; it is re-applied here
  // because the Teensy 3 core only latches a level once the pin is an output.
  void begin();
  void write(bool high) override;

 private:
  uint8_t pin_;
  volatile bool level_ = false;
};

// An edge interrupt (attachInterrupt, CHANGE). The interrupt reads the clock first, then the
// pin level, and hands both to the handler. A pulse shorter than the interrupt latency (well
// under a microsecond) can show the same level on both of its edges; camera feedback and
// PPS pulses last milliseconds.
class TeensyEdgeInput final : public hal::EdgeInput {
 public:
  // attachInterrupt() takes a plain function pointer, so each attached input occupies one of
  // this many fixed trampolines.
  static constexpr std::size_t kMaxAttached = 4;

  TeensyEdgeInput(uint8_t pin, pins::InputPull pull, const hal::Clock& clock)
      : pin_(pin), pull_(pull), clock_(clock) {}
  // The trampoline must never reach a destroyed object (on the device all are static).
  ~TeensyEdgeInput() override { detach(); }
  TeensyEdgeInput(const TeensyEdgeInput&) = delete;
  TeensyEdgeInput& operator=(const TeensyEdgeInput&) = delete;
  // Configures the pin as an input (with its pull-up if any).
  void begin();
  [[nodiscard]] bool attach(Handler handler, void* ctx) override;
  void detach() override;
  [[nodiscard]] bool read() const override;

  // Board-internal: called by this input's trampoline in interrupt context.
  void on_interrupt();

 private:
  uint8_t pin_;
  pins::InputPull pull_;
  const hal::Clock& clock_;
  int slot_ = -1;
  Handler handler_ = nullptr;
  void* ctx_ = nullptr;
};

// A one-shot alarm on an IntervalTimer (a PIT channel). arm_at() starts the timer with the
// delay to the deadline; the interrupt stops it (end()) before anything else, then either
// restarts it for the rest of the delay or calls the handler. The rest-of-delay path covers
// deadlines beyond one IntervalTimer period (the trigger allows 3600 s intervals, a PIT
// period tops out between 36 s and 179 s depending on the core and bus clock) and never
// lets the handler run early.
class TeensyAlarm final : public hal::Alarm {
 public:
  static constexpr std::size_t kMaxAlarms = 2;
  // Longest single IntervalTimer period used: under the shortest core limit (Teensy 3 with a
  // 120 MHz bus: 35.8 s); a long wait costs one extra interrupt per chunk.
  static constexpr uint32_t kMaxChunkUs = 20'000'000;
  // Shortest period both cores accept at every bus clock (Teensy 3 refuses fewer than 36 bus
  // cycles); past deadlines fire after this delay.
  static constexpr uint32_t kMinDelayUs = 4;
  // More urgent (numerically lower) than pin-change interrupts' default 128: a shot is not
  // held up by a feedback or PPS edge.
  static constexpr uint8_t kIrqPriority = 64;

  explicit TeensyAlarm(const hal::Clock& clock);
  ~TeensyAlarm() override;
  TeensyAlarm(const TeensyAlarm&) = delete;
  TeensyAlarm& operator=(const TeensyAlarm&) = delete;
  // Once, in setup(): sets the timer's interrupt priority.
  void begin();
  void set_handler(Handler handler, void* ctx) override;
  void arm_at(uint64_t t_us) override;
  void cancel() override;

  // IntervalTimer::begin() refusals (every PIT channel taken by other code). hal::Alarm
  // cannot report them to the core, so they are counted here; each one is a lost deadline.
  [[nodiscard]] uint32_t start_failures() const { return start_failures_; }

  // Board-internal: called by this alarm's trampoline in interrupt context.
  void on_interrupt();

 private:
  void start(uint64_t now_us);

  const hal::Clock& clock_;
  int slot_ = -1;
  Handler handler_ = nullptr;
  void* ctx_ = nullptr;
  // Written only while the timer is stopped (arm_at/cancel end() it first) or by the interrupt.
  uint64_t deadline_us_ = 0;
  volatile bool armed_ = false;
  volatile uint32_t start_failures_ = 0;
};

// The USB CDC Serial object as hal::ByteStream. Never blocks: writes are capped at
// Serial.availableForWrite(), reads at Serial.available().
class TeensyUsbSerial final : public hal::ByteStream {
 public:
  [[nodiscard]] std::size_t write(const uint8_t* data, std::size_t len) override;
  [[nodiscard]] std::size_t writable() const override;
  [[nodiscard]] std::size_t read(uint8_t* out, std::size_t cap) override;
  // A host has the port open with DTR asserted (pyserial and most terminals assert it).
  [[nodiscard]] bool connected() const override;
};

// The on-chip RTC (Teensy 3.6: RTC TSR; Teensy 4.1: SNVS) through Teensy3Clock, which both
// cores provide (on Teensy 4 it wraps rtc_get()/rtc_set()).
class TeensyRtc final : public hal::Rtc {
 public:
  // 2020-01-01T00:00:00Z. Earlier readings mean the RTC was never set or lost its battery.
  static constexpr int64_t kMinValidUtcS = 1'577'836'800;
  // Teensy3Clock counts 32-bit unsigned seconds.
  static constexpr int64_t kMaxUtcS = 0xFFFF'FFFFLL;

  [[nodiscard]] bool get_utc_s(int64_t& utc_s) const override;
  [[nodiscard]] bool set_utc_s(int64_t utc_s) override;
};

}  // namespace icgt::board::teensy
