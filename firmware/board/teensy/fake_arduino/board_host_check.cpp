// Host check of the Teensy board layer against the fake Teensyduino API in this folder.
// Built twice by firmware/cross/check_board_layer.sh (as Teensy 3.6 and as Teensy 4.1) with
// ASan/UBSan, linked with firmware/src/main.cpp, so the composition root runs too.
// Exit status 0 = every check passed; each failure prints its line.
#include <cstdio>
#include <cstring>
#include <vector>

#include "Arduino.h"
#include "Wire.h"
#include "fake_control.h"
#include "frame.hpp"
#include "pins.h"
#include "teensy_board.h"

namespace {

namespace tb = icgt::board::teensy;
namespace hal = icgt::hal;
namespace proto = icgt::proto;

int g_failures = 0;

#define CHECK(cond)                                                  \
  do {                                                               \
    if (!(cond)) {                                                   \
      std::printf("board_host_check:%d: FAILED: %s\n", __LINE__, #cond); \
      ++g_failures;                                                  \
    }                                                                \
  } while (0)

void wrap_extender_counts_wraps_even_when_preempted() {
  tb::WrapExtender ext;
  uint32_t counter = 0xFFFF'FFF0u;
  CHECK(ext.extend([&] { return counter; }) == 0xFFFF'FFF0u);
  counter = 0x10;
  CHECK(ext.extend([&] { return counter; }) == 0x1'0000'0010u);
  counter = 0x4000'0000u;  // observed every quarter period
  CHECK(ext.extend([&] { return counter; }) == 0x1'4000'0000u);
  counter = 0x8000'0000u;
  CHECK(ext.extend([&] { return counter; }) == 0x1'8000'0000u);
  counter = 0xC000'0000u;
  CHECK(ext.extend([&] { return counter; }) == 0x1'C000'0000u);
  // An "interrupt" observes the next wrap between our state load and our counter read.
  const uint64_t outer = ext.extend([&] {
    counter = 0x5;
    const uint64_t inner = ext.extend([&] { return counter; });
    CHECK(inner == 0x2'0000'0005u);
    return counter;
  });
  CHECK(outer == 0x2'0000'0005u);
  CHECK(ext.extend([&] { return counter; }) == 0x2'0000'0005u);  // no double count
  // A sample taken before that wrap (an edge stamp read at interrupt entry, extended after a
  // nested interrupt saw the wrap) belongs to the previous period, and moves nothing back.
  CHECK(ext.extend_sample(0xFFFF'FF00u) == 0x1'FFFF'FF00u);
  CHECK(ext.extend([&] { return counter; }) == 0x2'0000'0005u);
  CHECK(ext.extend_sample(0x6u) == 0x2'0000'0006u);
}

void clock_is_monotonic_across_the_micros_wrap() {
  fake::reset();
  fake::set_time_us(0xFFFF'F000u);
  tb::TeensyClock clock;
  clock.begin();
#if !defined(__IMXRT1062__)
  CHECK((ARM_DEMCR & ARM_DEMCR_TRCENA) != 0 && (ARM_DWT_CTRL & ARM_DWT_CTRL_CYCCNTENA) != 0);
#endif
  CHECK(clock.cycles_per_us() == fake::kCpuHz / 1'000'000);
  uint64_t last = clock.now_us();
  CHECK(last == 0xFFFF'F000u);
  for (int i = 0; i < 100; ++i) {
    fake::advance_us(97);
    const uint64_t now = clock.now_us();
    CHECK(now == fake::time_us());
    CHECK(now > last);
    last = now;
  }
  CHECK(clock.now_ns() == fake::time_us() * 1000u);
}

// Edge stamps come from the cycle counter read first in the interrupt, on the micros()
// timeline, across the counter's 32-bit wrap (every 7.2 s at 600 MHz, 23.9 s at 180 MHz).
void cycle_stamps_follow_the_micros_timeline_across_the_wrap() {
  fake::reset();
  const uint64_t mhz = fake::kCpuHz / 1'000'000;
  fake::set_time_us(5'000'000);
  // Put the counter's wrap 1 s after begin().
  fake::set_cycle_offset((uint64_t{1} << 32) - (6'000'000 * mhz) % (uint64_t{1} << 32));
  tb::TeensyClock clock;
  clock.begin();
  for (int i = 0; i < 40; ++i) {
    fake::advance_us(100'003);  // the loop reads the clock every 100 ms here
    (void)clock.now_us();
    const uint32_t raw = tb::TeensyClock::raw_cycles();
    CHECK(clock.stamp_us(raw) == fake::time_us());
  }
  // A raw count taken 3 us before a wrap, extended only after the clock has seen the wrap
  // (an edge interrupt preempted right after its counter read by one that reads the clock).
  const uint64_t next_wrap = ((fake::cycles() >> 32) + 1) << 32;
  const uint64_t wrap_us = (next_wrap - (fake::cycles() - fake::time_us() * mhz) + mhz - 1) / mhz;
  while (fake::time_us() + 200'000 < wrap_us) {
    fake::advance_us(100'000);
    (void)clock.now_us();
  }
  const uint64_t before_us = wrap_us - 3;
  fake::set_time_us(before_us);
  const uint32_t early_raw = tb::TeensyClock::raw_cycles();
  fake::set_time_us(before_us + 6);
  (void)clock.now_us();  // sees the wrap
  CHECK(clock.stamp_us(early_raw) == before_us);
  CHECK(clock.stamp_us(tb::TeensyClock::raw_cycles()) == before_us + 6);
}

void i2c_maps_wire_results() {
  fake::reset();
  tb::TeensyI2cBus bus(Wire);
  bus.begin();
  CHECK(fake::wire_clock_hz() == 400'000);
  CHECK(tb::TeensyI2cBus::map_end_transmission(0) == hal::I2cStatus::ok);
  CHECK(tb::TeensyI2cBus::map_end_transmission(1) == hal::I2cStatus::bus_error);
  CHECK(tb::TeensyI2cBus::map_end_transmission(2) == hal::I2cStatus::nack_address);
  CHECK(tb::TeensyI2cBus::map_end_transmission(4) == hal::I2cStatus::timeout);
#if defined(__IMXRT1062__)
  CHECK(tb::TeensyI2cBus::map_end_transmission(3) == hal::I2cStatus::bus_error);  // never returned
  CHECK(tb::TeensyI2cBus::map_end_transmission(5) == hal::I2cStatus::bus_error);  // FIFO error
#else
  CHECK(tb::TeensyI2cBus::map_end_transmission(3) == hal::I2cStatus::nack_data);
  CHECK(tb::TeensyI2cBus::map_end_transmission(5) == hal::I2cStatus::bus_error);  // never returned
#endif

  const uint8_t reg = 0x08;
  uint8_t out[4] = {};
  fake::wire_script(0, {1, 2, 3, 4}, 4);
  std::size_t calls = fake::wire_calls().size();
  CHECK(bus.transfer(0x28, &reg, 1, out, 4, hal::I2cJoin::repeated_start) == hal::I2cStatus::ok);
  CHECK(out[0] == 1 && out[3] == 4);
  CHECK(fake::wire_calls().size() == calls + 2);
  CHECK(fake::wire_calls()[calls].kind == 'w' && fake::wire_calls()[calls].send_stop == 0);
  CHECK(fake::wire_calls()[calls + 1].kind == 'r' && fake::wire_calls()[calls + 1].count == 4);

  calls = fake::wire_calls().size();
  CHECK(bus.transfer(0x62, &reg, 1, out, 2, hal::I2cJoin::stop) == hal::I2cStatus::ok);
  CHECK(fake::wire_calls()[calls].send_stop == 1);

  fake::wire_script(0, {1, 2, 3, 4}, 2);  // the part stops answering halfway
  CHECK(bus.transfer(0x28, &reg, 1, out, 4, hal::I2cJoin::repeated_start) == hal::I2cStatus::bus_error);
  CHECK(Wire.available() == 0);

  // Faults with each core's own codes.
  fake::wire_script(0, {9, 9, 9, 9}, 4);
  fake::wire_fault(fake::WireFault::nack_address);
  calls = fake::wire_calls().size();
  CHECK(bus.transfer(0x28, &reg, 1, out, 4, hal::I2cJoin::repeated_start) == hal::I2cStatus::nack_address);
  CHECK(fake::wire_calls().size() == calls + 1);  // no read after a refused write
  CHECK(bus.transfer(0x28, nullptr, 0, out, 4, hal::I2cJoin::repeated_start) == hal::I2cStatus::nack_address);
  CHECK(bus.transfer(0x28, nullptr, 0, nullptr, 0, hal::I2cJoin::stop) == hal::I2cStatus::nack_address);
  fake::wire_fault(fake::WireFault::nack_data);
  const uint8_t two[2] = {0x3D, 0x0C};
#if defined(__IMXRT1062__)
  CHECK(bus.transfer(0x28, two, 2, nullptr, 0, hal::I2cJoin::stop) == hal::I2cStatus::nack_address);
#else
  CHECK(bus.transfer(0x28, two, 2, nullptr, 0, hal::I2cJoin::stop) == hal::I2cStatus::nack_data);
#endif
  // A stuck bus costs the core's 16 ms wait and is a timeout, also for a 4-byte read-only
  // transfer, where Teensy 4's requestFrom() returns 4 (the count asked for) with nothing read.
  fake::wire_fault(fake::WireFault::stuck_bus);
  uint64_t t0 = fake::time_us();
  CHECK(bus.transfer(0x28, &reg, 1, out, 4, hal::I2cJoin::repeated_start) == hal::I2cStatus::timeout);
  CHECK(fake::time_us() - t0 == fake::kStuckBusWaitUs);
  t0 = fake::time_us();
  const hal::I2cStatus read_only = bus.transfer(0x28, nullptr, 0, out, 4, hal::I2cJoin::repeated_start);
#if defined(__IMXRT1062__)
  CHECK(read_only == hal::I2cStatus::timeout);
#else
  CHECK(read_only == hal::I2cStatus::nack_address);  // Teensy 3's requestFrom() says 0 for both
#endif
  CHECK(fake::time_us() - t0 == fake::kStuckBusWaitUs);
  fake::wire_fault(fake::WireFault::fifo_error);
#if defined(__IMXRT1062__)
  CHECK(bus.transfer(0x28, &reg, 1, out, 4, hal::I2cJoin::repeated_start) == hal::I2cStatus::bus_error);
#else
  CHECK(bus.transfer(0x28, &reg, 1, out, 4, hal::I2cJoin::repeated_start) == hal::I2cStatus::timeout);
#endif
  fake::wire_fault(fake::WireFault::none);

  uint8_t big[tb::TeensyI2cBus::kMaxTransferBytes + 1] = {};
  calls = fake::wire_calls().size();
  CHECK(bus.transfer(0x28, big, sizeof big, nullptr, 0, hal::I2cJoin::stop) == hal::I2cStatus::bus_error);
  CHECK(bus.transfer(0x28, &reg, 1, big, sizeof big, hal::I2cJoin::stop) == hal::I2cStatus::bus_error);
  CHECK(fake::wire_calls().size() == calls);  // refused before touching the bus
  fake::wire_script(0, {}, 0);
}

struct AlarmLog {
  int fired = 0;
  uint64_t at_us = 0;
};

void on_alarm(void* ctx, uint64_t now_us) {
  auto* log = static_cast<AlarmLog*>(ctx);
  ++log->fired;
  log->at_us = now_us;
  digitalWriteFast(41, HIGH);  // stands for the shutter line: the fake records the priority
}

void alarm_fires_once_at_the_deadline_never_early() {
  fake::set_time_us(1'000);
  tb::TeensyClock clock;
  tb::TeensyAlarm alarm(clock);  // the second alarm: main.cpp's trigger alarm holds the first
  alarm.begin();
  AlarmLog log;
  alarm.set_handler(&on_alarm, &log);

  const uint64_t deadline = fake::time_us() + 100'000'000;  // beyond one IntervalTimer period
  alarm.arm_at(deadline);
  CHECK(fake::last_timer_period_us() == tb::TeensyAlarm::kMaxChunkUs);
  CHECK(fake::last_timer_priority() == tb::TeensyAlarm::kIrqPriority);
  fake::advance_us(deadline - fake::time_us() - 1);
  CHECK(log.fired == 0);
  fake::advance_us(1);
  CHECK(log.fired == 1 && log.at_us == deadline);
  // The handler ran at the alarm's priority, above USB, on both boards (on Teensy 4 an
  // end() before the handler would have run it at 255).
  CHECK(fake::pin_write_priority(41) == tb::irq::kTriggerAlarm);
  CHECK(tb::irq::kTriggerAlarm < fake::nvic_priority(fake::usb_irq()));
  CHECK(fake::timers_running() == 0);  // one-shot: ended in the interrupt
  fake::advance_us(200'000'000);
  CHECK(log.fired == 1);

  alarm.arm_at(fake::time_us() - 5);  // in the past: at once
  fake::advance_us(tb::TeensyAlarm::kMinDelayUs);
  CHECK(log.fired == 2);
  CHECK(fake::pin_write_priority(41) == tb::irq::kTriggerAlarm);

  alarm.arm_at(fake::time_us() + 1'000);
  alarm.arm_at(fake::time_us() + 3'000);  // re-arming replaces the pending time
  fake::advance_us(2'000);
  CHECK(log.fired == 2);
  fake::advance_us(1'000);
  CHECK(log.fired == 3);

  alarm.arm_at(fake::time_us() + 1'000);
  alarm.cancel();
  fake::advance_us(5'000);
  CHECK(log.fired == 3);
  CHECK(alarm.start_failures() == 0);

  tb::TeensyAlarm third(clock);  // no timer slot left: counted, never crashes
  third.arm_at(fake::time_us() + 10);
  CHECK(third.start_failures() == 1);
}

struct EdgeLog {
  int edges = 0;
  bool level = false;
  uint64_t t_us = 0;
};

void on_edge(void* ctx, bool level_high, uint64_t t_us) {
  auto* log = static_cast<EdgeLog*>(ctx);
  ++log->edges;
  log->level = level_high;
  log->t_us = t_us;
}

void edge_input_stamps_both_edges_until_detached() {
  tb::TeensyClock clock;
  clock.begin();
  tb::TeensyEdgeInput in(40, tb::pins::InputPull::up, clock);
  in.begin();
  CHECK(fake::pin_mode(40) == INPUT_PULLUP);
  EdgeLog log;
  CHECK(in.attach(&on_edge, &log));
  // The pin's interrupt now runs above USB (both cores leave it at 128).
  CHECK(in.irq_number() == fake::pin_irq(40));
  CHECK(fake::nvic_priority(fake::pin_irq(40)) == tb::irq::kEdgeInputs);
  CHECK(tb::irq::kEdgeInputs < fake::nvic_priority(fake::usb_irq()));
  fake::set_input(40, true);
  fake::advance_us(123);
  fake::set_input(40, false);
  CHECK(log.edges == 2 && !log.level && log.t_us == fake::time_us());
  // The stamp is the cycle counter read inside the interrupt.
  CHECK(fake::last_cyccnt_read_priority() == tb::irq::kEdgeInputs);
  CHECK(fake::last_cyccnt_read_cycles() == fake::cycles());
  CHECK(!in.read());
  in.detach();
  CHECK(!fake::interrupt_attached(40));
  fake::set_input(40, true);
  CHECK(log.edges == 2);
  CHECK(!in.attach(nullptr, nullptr));

  tb::TeensyEdgeInput bad(NUM_DIGITAL_PINS, tb::pins::InputPull::none, clock);
  CHECK(!bad.attach(&on_edge, &log));  // a pin that cannot interrupt
}

void usb_serial_write_failures_send_nothing() {
  fake::reset();
  fake::serial_set_connected(true);
  tb::TeensyUsbSerial link;
  const uint8_t bytes[3] = {1, 2, 3};
  CHECK(link.write(bytes, 3) == 3);
  fake::serial_fail_writes(true);  // Teensy 3: (size_t)-1, Teensy 4: 0
  CHECK(link.write(bytes, 3) == 0);
#if defined(__IMXRT1062__)
  CHECK(link.write_errors() == 0);  // 0 is "took nothing", not an error value
#else
  CHECK(link.write_errors() == 1);
#endif
  fake::serial_fail_writes(false);
  CHECK(fake::serial_tx().size() == 3);
}

void rtc_counts_only_after_our_own_set_time() {
  fake::reset();
  fake::set_micros_step_us(1);  // the read-back busy-waits on micros()
  tb::TeensyRtc rtc;
  int64_t s = 0;
  fake::rtc_set_raw(86'400);
  CHECK(!rtc.get_utc_s(s));
  // Coin cell in: the core writes its time (Teensy 3: the build time, after 2020).
  fake::rtc_vbat_power_up();
  CHECK(!rtc.get_utc_s(s));
  fake::rtc_upload();
  CHECK(!rtc.get_utc_s(s));
  CHECK(!rtc.set_utc_s(1'500'000'000));
  CHECK(!rtc.marker_present());

  CHECK(rtc.set_utc_s(1'790'000'000));  // Teensy 4: read back after the resync (92 us)
  CHECK(rtc.marker_present());
  CHECK(rtc.get_utc_s(s) && s >= 1'790'000'000 && s <= 1'790'000'001);
  // Teensy 3: the core's stale-time flag was cleared, so the next upload keeps our time.
  fake::rtc_upload();
  CHECK(rtc.get_utc_s(s) && s >= 1'790'000'000 && s <= 1'790'000'001);
  // Somebody sets it back (an older build time): no longer ours.
  fake::rtc_set_raw(fake::kBuildTimeS);
  CHECK(!rtc.get_utc_s(s));
  // The coin cell goes: marker gone with the time.
  CHECK(rtc.set_utc_s(1'790'000'100));
  fake::rtc_vbat_power_up();
  CHECK(!rtc.get_utc_s(s));

#if defined(__IMXRT1062__)
  // The HP counter never resyncs: the read-back gives up at its deadline, no marker written.
  fake::rtc_set_sync_delay_us(UINT64_MAX);
  const uint64_t t0 = fake::time_us();
  CHECK(!rtc.set_utc_s(1'790'000'200));
  CHECK(fake::time_us() - t0 >= tb::TeensyRtc::kReadBackDeadlineUs);
  CHECK(fake::time_us() - t0 <= tb::TeensyRtc::kReadBackDeadlineUs + 10);
  CHECK(!rtc.marker_present() && !rtc.get_utc_s(s));
  fake::rtc_set_sync_delay_us(92);
#endif
  fake::set_micros_step_us(0);
}

// Runs setup() and loop() from main.cpp on the fake board: HELLO, STATUS, a PING answered,
// and a single shot fired by the alarm interrupt.
void composition_root_runs_on_the_fake_board() {
  fake::reset();
  fake::serial_set_connected(true);
  setup();
  CHECK(fake::pin_mode(tb::pins::kShutter) == OUTPUT && !fake::pin_level(tb::pins::kShutter));
  CHECK(fake::pin_mode(tb::pins::kFocus) == OUTPUT);
  CHECK(fake::pin_mode(tb::pins::kFeedback) == INPUT_PULLUP);
  CHECK(fake::pin_mode(tb::pins::kPps) == INPUT);
  CHECK(fake::interrupt_attached(tb::pins::kFeedback));
  CHECK(fake::interrupt_attached(tb::pins::kPps));
  CHECK(fake::nvic_priority(fake::pin_irq(tb::pins::kFeedback)) == tb::irq::kEdgeInputs);
  CHECK(fake::nvic_priority(fake::pin_irq(tb::pins::kPps)) == tb::irq::kEdgeInputs);

  uint8_t wire[proto::kMaxWireBytes];
  proto::Ping ping;
  ping.nonce = 0xC0FFEE;
  std::size_t n = proto::encode_message(ping, 1, 0, wire, sizeof wire);
  fake::serial_push_rx(std::vector<uint8_t>(wire, wire + n));
  proto::StartCapture shot;
  shot.mode = static_cast<uint8_t>(proto::CaptureMode::single);
  shot.shutter_pulse_us = 20'000;
  n = proto::encode_message(shot, 2, 0, wire, sizeof wire);
  fake::serial_push_rx(std::vector<uint8_t>(wire, wire + n));

  for (int i = 0; i < 2'500; ++i) {  // 2.5 s of 1 ms loop iterations
    loop();
    fake::advance_us(1'000);
  }

  proto::StreamDecoder rx;
  int hello = 0, status = 0, ping_acks = 0, exposures = 0;
  for (uint8_t b : fake::serial_tx()) {
    if (rx.push(b) != proto::StreamDecoder::Status::frame) continue;
    proto::Hello h;
    proto::Ack a;
    proto::Exposure e;
    if (rx.decode(h)) {
      ++hello;
      CHECK(std::strcmp(h.firmware_version, "0.1.0") == 0);
#if defined(__IMXRT1062__)
      CHECK(h.board == static_cast<uint8_t>(proto::Board::teensy41));
#else
      CHECK(h.board == static_cast<uint8_t>(proto::Board::teensy36));
#endif
    }
    if (rx.header().type == static_cast<uint8_t>(proto::MsgId::STATUS)) ++status;
    if (rx.decode(a) && a.request_type == static_cast<uint8_t>(proto::MsgId::PING) && a.detail == 0xC0FFEE) {
      ++ping_acks;
    }
    if (rx.decode(e)) ++exposures;
  }
  CHECK(rx.stats().rejected() == 0);
  CHECK(hello == 1);
  CHECK(status >= 2);
  CHECK(ping_acks == 1);
  CHECK(exposures == 1);  // no feedback edge: reported as feedback_missing after the timeout
  CHECK(fake::pin_writes(tb::pins::kShutter) >= 3);  // inactive at start, asserted, released
  // Released by the trigger alarm's interrupt at the alarm's priority.
  CHECK(fake::pin_write_priority(tb::pins::kShutter) == tb::irq::kTriggerAlarm);
  CHECK(!fake::pin_level(tb::pins::kShutter));
  CHECK(fake::serial_send_now_calls() > 0);
}

}  // namespace

int main() {
  wrap_extender_counts_wraps_even_when_preempted();
  clock_is_monotonic_across_the_micros_wrap();
  cycle_stamps_follow_the_micros_timeline_across_the_wrap();
  i2c_maps_wire_results();
  alarm_fires_once_at_the_deadline_never_early();
  edge_input_stamps_both_edges_until_detached();
  usb_serial_write_failures_send_nothing();
  rtc_counts_only_after_our_own_set_time();
  composition_root_runs_on_the_fake_board();
  if (g_failures != 0) {
    std::printf("board_host_check: %d check(s) failed\n", g_failures);
    return 1;
  }
  std::printf("board_host_check: all checks passed\n");
  return 0;
}
