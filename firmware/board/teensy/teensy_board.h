// The Teensy board layer: the hal interfaces implemented with documented Teensyduino APIs
// (micros(), Wire, digitalWriteFast/digitalReadFast, attachInterrupt, IntervalTimer, the USB
// Serial object, Teensy3Clock) and a few documented registers (ARM_DWT_CYCCNT, NVIC_SET_PRIORITY,
// the battery-backed registers of the RTC marker). This header and teensy_board.cpp are the only firmware
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
#include "irq_priorities.h"
#include "pins.h"

class TwoWire;  // Wire.h; both Teensy cores name the class TwoWire

namespace icgt::board::teensy {

// Extends a free-running 32-bit counter to 64 bits, lock-free, callable from the loop and
// from any interrupt (nested or not).
//
// state_ packs the wrap count (upper 29 bits), a "primed" bit (2) and the counter's top two
// bits (its quadrant) at the newest observation (bits 1..0). A sample is placed relative to that observation:
// one quadrant behind is an OLDER sample (taken before the newest observation, e.g. an edge
// stamp read at interrupt entry and extended after a nested interrupt observed the counter),
// anything else is the same quadrant or later. Only later samples are published, with a
// compare-exchange, so a preempted reader never moves the state backwards.
// Requirements: the counter is observed at least once per quarter period (2^30 ticks: 1.8 s
// of the 600 MHz Teensy 4 cycle counter, 6 s at the Teensy 3.6's 180 MHz, 18 min of
// micros()), and extend_sample() gets samples at most a quarter period old. The main loop
// reads the clock many times per millisecond.
class WrapExtender {
 public:
  // Reads the counter now: the state is loaded first, so the sample is never older than it.
  template <class ReadCounter>
  [[nodiscard]] uint64_t extend(ReadCounter read_counter) {
    const uint32_t seen = state_.load(std::memory_order_acquire);
    return place(seen, read_counter());
  }
  // A sample taken earlier (at most a quarter period before the newest observation).
  [[nodiscard]] uint64_t extend_sample(uint32_t raw) { return place(state_.load(std::memory_order_acquire), raw); }

 private:
  static constexpr uint32_t kPrimed = 4;  // bit 2: a first observation exists

  [[nodiscard]] uint64_t place(uint32_t seen, uint32_t raw) {
    uint32_t wraps = seen >> 3;
    const uint32_t q_seen = seen & 3u;
    const uint32_t q = raw >> 30;
    if ((seen & kPrimed) != 0) {
      if (((q - q_seen) & 3u) == 3u) {
        // One quadrant behind the newest observation: older. If that observation is just
        // past a wrap, the sample is from before it.
        if (q_seen == 0 && wraps > 0) --wraps;
        return (uint64_t{wraps} << 32) | raw;
      }
      if (q < q_seen) ++wraps;  // ahead, across the wrap
    }
    const uint32_t next = (wraps << 3) | kPrimed | q;
    if (next != seen) {
      uint32_t expected = seen;
      // Failure means a newer observation got there first; ours adds nothing.
      (void)state_.compare_exchange_strong(expected, next, std::memory_order_acq_rel, std::memory_order_acquire);
    }
    return (uint64_t{wraps} << 32) | raw;
  }

  std::atomic<uint32_t> state_{0};
};

// The device clock. now_us() is micros() extended to 64 bits (what the core and the loop
// read). Beside it the ARM DWT cycle counter (ARM_DWT_CYCCNT: 600 MHz on Teensy 4.1, 180 MHz
// on Teensy 3.6; Teensy 4's start-up enables it, begin() enables it on Teensy 3) is kept
// extended too, anchored to the micros() timeline in begin(): edge interrupts read the raw
// counter as their first instruction (one load) and stamp_us() turns it into microseconds
// of the same timeline afterwards, so the stamp is taken at interrupt entry rather than
// after micros()' own work, with the counter's 1.7 ns / 5.6 ns resolution up to the final
// truncation to whole microseconds (the hal's unit). micros() is derived from the same core
// clock on both boards (SysTick on Teensy 3, the cycle counter itself on Teensy 4), so the
// two never drift apart; the firmware never changes the CPU clock after begin().
class TeensyClock final : public hal::Clock {
 public:
  // Once, in setup(), before anything reads the cycle timeline.
  void begin();
  [[nodiscard]] uint64_t now_us() const override;
  // The raw cycle counter (interrupt entry).
  [[nodiscard]] static uint32_t raw_cycles();
  // A raw cycle count read at most a quarter period ago, on the now_us() timeline.
  [[nodiscard]] uint64_t stamp_us(uint32_t raw_cycles) const;
  // Nanoseconds on the now_us() timeline, from the cycle counter. Board-only: hal::Clock is
  // microseconds, so the core never sees this resolution.
  [[nodiscard]] uint64_t now_ns() const;
  [[nodiscard]] uint32_t cycles_per_us() const { return cycles_per_us_; }

 private:
  mutable WrapExtender micros_;
  mutable WrapExtender cycles_;
  uint64_t anchor_us_ = 0;
  uint64_t anchor_cycles_ = 0;
  uint32_t cycles_per_us_ = 1;
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

  // Wire.endTransmission() result codes as the hal sees them. These are the codes the
  // Teensy Wire library really returns (PaulStoffregen/Wire 1.58/1.59), not Arduino's
  // documented set (there 5 is a timeout):
  //  - Teensy 3 (WireKinetis): 0 ok, 1 too long, 2 address NACK, 3 data NACK, 4 for every
  //    bus fault: bus busy > 16 ms (after a 9-clock recovery at 15 ms), START not taken in
  //    4 ms, a byte stretched > 5 ms, arbitration lost. Never 5.
  //  - Teensy 4 (WireIMXRT): 0 ok, 1 too long, 2 any NACK (it cannot tell address from
  //    data: nack_data never occurs), 4 bus not idle after 16 ms (and a failed recovery),
  //    SCL/SDA low 15 ms (pin-low timeout), transfer > 50 ms or arbitration lost, 5 LPI2C
  //    FIFO error.
  // Code 4 is mapped to timeout on both: all but the rare arbitration loss are the bus or a
  // part holding a line.
  [[nodiscard]] static hal::I2cStatus map_end_transmission(uint8_t code);
  // Wire.requestFrom() results: Teensy 3 returns the byte count, 0 on any failure; Teensy 4
  // returns the count, but 4 (not a count) when the bus never went idle, with nothing
  // received. A read is only ok when the count and Wire.available() both equal the request.
  [[nodiscard]] static hal::I2cStatus map_request_from(uint8_t got, int available, std::size_t wanted);

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

// An edge interrupt (attachInterrupt, CHANGE) at irq::kEdgeInputs, above USB. The interrupt
// reads the raw cycle counter first, then the pin level, converts the count to device
// microseconds (TeensyClock::stamp_us) and hands both to the handler. A pulse shorter than
// the interrupt latency (well under a microsecond) can show the same level on both of its
// edges; camera feedback and PPS pulses last milliseconds.
//
// Entry-to-stamp latency (the edge to the counter read), by count, not measured on a board
// (no hardware here; firmware/board/teensy/README.md "ISR latency" says how it was counted):
// Teensy 4.1 ~0.1 us, Teensy 3.6 ~0.2-0.3 us when nothing more urgent runs; add the alarm
// handler's few microseconds if a shot is being fired at that instant.
class TeensyEdgeInput final : public hal::EdgeInput {
 public:
  // attachInterrupt() takes a plain function pointer, so each attached input occupies one of
  // this many fixed trampolines.
  static constexpr std::size_t kMaxAttached = 4;

  TeensyEdgeInput(uint8_t pin, pins::InputPull pull, const TeensyClock& clock)
      : pin_(pin), pull_(pull), clock_(clock) {}
  // The trampoline must never reach a destroyed object (on the device all are static).
  ~TeensyEdgeInput() { detach(); }
  TeensyEdgeInput(const TeensyEdgeInput&) = delete;
  TeensyEdgeInput& operator=(const TeensyEdgeInput&) = delete;
  // Configures the pin as an input (with its pull-up if any).
  void begin();
  [[nodiscard]] bool attach(Handler handler, void* ctx) override;
  void detach() override;
  [[nodiscard]] bool read() const override;

  // The NVIC interrupt this pin's edges arrive on (Teensy 4: IRQ_GPIO6789 for every pin;
  // Teensy 3: the pin's port, IRQ_PORTA..IRQ_PORTE), -1 if none.
  [[nodiscard]] int irq_number() const;

  // Board-internal: called by this input's trampoline in interrupt context with the cycle
  // count the trampoline read first.
  void on_interrupt(uint32_t raw_cycles);

 private:
  uint8_t pin_;
  pins::InputPull pull_;
  const TeensyClock& clock_;
  int slot_ = -1;
  Handler handler_ = nullptr;
  void* ctx_ = nullptr;
};

// A one-shot alarm on an IntervalTimer (a PIT channel) at irq::kTriggerAlarm. arm_at() starts
// the timer with the delay to the deadline; the interrupt either restarts it for the rest of
// the delay or calls the handler and then stops it (end()), unless the handler armed it
// again. The handler runs BEFORE end(): on Teensy 4, end() drops the shared PIT interrupt to
// priority 255 when no other channel runs, and the shot would run at the lowest priority of
// the chip (irq_priorities.h). The rest-of-delay path covers
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
  static constexpr uint8_t kIrqPriority = irq::kTriggerAlarm;

  explicit TeensyAlarm(const hal::Clock& clock);
  ~TeensyAlarm();
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
  volatile uint32_t generation_ = 0;  // arm_at()/cancel() count: did the handler re-arm?
  volatile uint32_t start_failures_ = 0;
};

// The USB CDC Serial object as hal::ByteStream. Never blocks: writes are capped at
// Serial.availableForWrite(), reads at Serial.available().
// Serial.write() failures: Teensy 3's usb_serial_write() returns int -1 when USB is not
// configured or a packet timed out, which Serial.write() hands on as (size_t)-1; Teensy 4
// returns 0 (not configured) or the bytes it took before a timeout. A result above the
// request is a failure: nothing is counted as sent, write_errors() counts it, and the
// outbox keeps the bytes for the next try.
class TeensyUsbSerial final : public hal::ByteStream {
 public:
  [[nodiscard]] uint32_t write_errors() const { return write_errors_; }
  [[nodiscard]] std::size_t write(const uint8_t* data, std::size_t len) override;
  [[nodiscard]] std::size_t writable() const override;
  [[nodiscard]] std::size_t read(uint8_t* out, std::size_t cap) override;
  // A host has the port open with DTR asserted (pyserial and most terminals assert it).
  [[nodiscard]] bool connected() const override;

 private:
  uint32_t write_errors_ = 0;
};

// The on-chip RTC (Teensy 3.6: RTC TSR; Teensy 4.1: SNVS) through Teensy3Clock, which both
// cores provide (on Teensy 4 it wraps rtc_get()/rtc_set()).
//
// Validity: the RTC's time counts only once this firmware has set it (SET_TIME). A marker in
// battery-backed registers says so: three words {magic, set_s, check} in the Teensy 4's
// SNVS_LPGPR0..2 or the K66 VBAT register file words 0..2 (0x4003E000; word 7 belongs to the
// core). Both live and die with the RTC on VBAT. Without it the time is somebody else's:
// Teensy 3's start-up writes the sketch's build time (local time of the build machine) after
// a VBAT power-up and again after the next upload; Teensy 4's writes 2019-01-01 after a
// VBAT power-up. The marker is also refused if the RTC reads earlier than set_s (it was set
// back since). Not caught: an upload-time write of a LATER time on a board that had been set
// by us (the Teensy 4 loader can write the PC's time); the host sees HELLO.rtc_utc_us_at_boot
// and its own clock check.
// On Teensy 3 set_utc_s() also clears the core's "stale build time" flag (VBAT word 7), as
// the core itself does once a fresh time is in, so the next upload does not overwrite ours.
//
// Teensy 4's rtc_set() restarts the SRTC and asks the HP counter to resync (HP_TS) without
// waiting; the HP counter that rtc_get() reads catches up a few 32 kHz cycles later. The
// read-back therefore polls until the new second shows, with a deadline.
class TeensyRtc final : public hal::Rtc {
 public:
  // 2020-01-01T00:00:00Z. Earlier readings mean the RTC was never set or lost its battery.
  static constexpr int64_t kMinValidUtcS = 1'577'836'800;
  // Teensy3Clock counts 32-bit unsigned seconds.
  static constexpr int64_t kMaxUtcS = 0xFFFF'FFFFLL;
  static constexpr uint32_t kMarkerMagic = 0x49'43'47'54;  // "ICGT"
  // Read-back deadline after a write: 32 cycles of the 32.768 kHz clock; the resync takes a
  // few, and a Teensy 3 TSR write reads back at once.
  static constexpr uint32_t kReadBackDeadlineUs = 1'000;

  [[nodiscard]] bool get_utc_s(int64_t& utc_s) const override;
  [[nodiscard]] bool set_utc_s(int64_t utc_s) override;
  [[nodiscard]] bool marker_present() const;
};

}  // namespace icgt::board::teensy
