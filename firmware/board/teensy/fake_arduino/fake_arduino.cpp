// Behaviour of the fake Teensyduino API: a deterministic, single-threaded model good enough to
// run the board layer and the composition root on the host. State lives in function-local
// statics so the static constructors of main.cpp may call in before main().
#include <algorithm>
#include <cstring>
#include <map>

#include "Arduino.h"
#include "IntervalTimer.h"
#include "Wire.h"
#include "fake_control.h"

namespace {

struct Pin {
  int mode = -1;
  bool level = false;
  uint32_t writes = 0;
  void (*isr)() = nullptr;
};

struct Timer {
  bool running = false;
  void (*funct)() = nullptr;
  uint64_t period_us = 0;
  uint64_t next_us = 0;
  uint8_t priority = 128;
};

struct State {
  uint64_t now_us = 0;
  std::map<uint8_t, Pin> pins;
  std::vector<Timer> timers;
  uint64_t last_period_us = 0;
  uint8_t last_priority = 0;
  // Wire
  uint32_t wire_clock_hz = 100'000;
  bool transmitting = false;
  uint8_t tx_address = 0;
  std::vector<uint8_t> tx;
  uint8_t end_code = 0;
  std::vector<uint8_t> read_data;
  std::size_t deliver = 0;
  std::vector<uint8_t> rx;
  std::size_t rx_pos = 0;
  std::vector<fake::WireCall> calls;
  // Serial
  bool connected = false;
  int room = 4096;
  std::vector<uint8_t> serial_rx;
  std::size_t serial_rx_pos = 0;
  std::vector<uint8_t> serial_tx;
  uint32_t send_now_calls = 0;
  unsigned long rtc_s = 0;
};

State& st() {
  static State s;
  return s;
}

}  // namespace

volatile uint32_t F_CPU_ACTUAL = fake::kCpuHz;
volatile uint32_t fake_arm_dwt_cyccnt = 0;
usb_serial_class Serial;
teensy3_clock_class Teensy3Clock;
TwoWire Wire;

uint32_t micros() { return static_cast<uint32_t>(st().now_us); }
uint32_t millis() { return static_cast<uint32_t>(st().now_us / 1000); }
void pinMode(uint8_t pin, uint8_t mode) { st().pins[pin].mode = mode; }
void digitalWriteFast(uint8_t pin, uint8_t val) {
  Pin& p = st().pins[pin];
  p.level = val != 0;
  ++p.writes;
}
uint8_t digitalReadFast(uint8_t pin) { return st().pins[pin].level ? 1 : 0; }
void attachInterrupt(uint8_t pin, void (*function)(void), int mode) {
  if (mode == CHANGE) st().pins[pin].isr = function;
}
void detachInterrupt(uint8_t pin) { st().pins[pin].isr = nullptr; }
void noInterrupts() {}
void interrupts() {}

void usb_serial_class::begin(long) {}
int usb_serial_class::available() { return static_cast<int>(st().serial_rx.size() - st().serial_rx_pos); }
int usb_serial_class::read() {
  State& s = st();
  return s.serial_rx_pos < s.serial_rx.size() ? s.serial_rx[s.serial_rx_pos++] : -1;
}
int usb_serial_class::availableForWrite() { return st().connected ? st().room : 0; }
size_t usb_serial_class::write(uint8_t b) { return write(&b, 1); }
size_t usb_serial_class::write(const uint8_t* buffer, size_t size) {
  State& s = st();
  if (!s.connected) return 0;
  s.serial_tx.insert(s.serial_tx.end(), buffer, buffer + size);
  return size;
}
void usb_serial_class::send_now() { ++st().send_now_calls; }
uint8_t usb_serial_class::dtr() { return st().connected ? 1 : 0; }
usb_serial_class::operator bool() { return st().connected; }

unsigned long teensy3_clock_class::get() { return st().rtc_s + static_cast<unsigned long>(st().now_us / 1'000'000); }
void teensy3_clock_class::set(unsigned long t) { st().rtc_s = t - static_cast<unsigned long>(st().now_us / 1'000'000); }

void TwoWire::begin() {}
void TwoWire::setClock(uint32_t frequency) { st().wire_clock_hz = frequency; }
void TwoWire::beginTransmission(uint8_t address) {
  State& s = st();
  s.transmitting = true;
  s.tx_address = address;
  s.tx.clear();
}
void TwoWire::beginTransmission(int address) { beginTransmission(static_cast<uint8_t>(address)); }
uint8_t TwoWire::endTransmission(uint8_t sendStop) {
  State& s = st();
  s.transmitting = false;
  s.calls.push_back({'w', s.tx_address, static_cast<uint8_t>(s.tx.size()), sendStop});
  return s.end_code;
}
uint8_t TwoWire::endTransmission() { return endTransmission(1); }
uint8_t TwoWire::requestFrom(uint8_t address, uint8_t quantity, uint8_t sendStop) {
  State& s = st();
  s.calls.push_back({'r', address, quantity, sendStop});
  const std::size_t n = std::min<std::size_t>({quantity, s.deliver, s.read_data.size()});
  s.rx.assign(s.read_data.begin(), s.read_data.begin() + static_cast<long>(n));
  s.rx_pos = 0;
  return static_cast<uint8_t>(n);
}
uint8_t TwoWire::requestFrom(uint8_t address, uint8_t quantity) {
  return requestFrom(address, quantity, static_cast<uint8_t>(1));
}
uint8_t TwoWire::requestFrom(int address, int quantity, int sendStop) {
  return requestFrom(static_cast<uint8_t>(address), static_cast<uint8_t>(quantity), static_cast<uint8_t>(sendStop));
}
uint8_t TwoWire::requestFrom(int address, int quantity) { return requestFrom(address, quantity, 1); }
size_t TwoWire::write(uint8_t data) { return write(&data, 1); }
size_t TwoWire::write(const uint8_t* data, size_t quantity) {
  State& s = st();
  if (!s.transmitting) return 0;
  const std::size_t room = 32 - std::min<std::size_t>(32, s.tx.size());  // Teensy 3's buffer
  const std::size_t n = std::min(room, quantity);
  s.tx.insert(s.tx.end(), data, data + n);
  return n;
}
int TwoWire::available() { return static_cast<int>(st().rx.size() - st().rx_pos); }
int TwoWire::read() {
  State& s = st();
  return s.rx_pos < s.rx.size() ? s.rx[s.rx_pos++] : -1;
}

IntervalTimer::IntervalTimer() : id_(static_cast<int>(st().timers.size())) { st().timers.emplace_back(); }
IntervalTimer::~IntervalTimer() = default;
bool IntervalTimer::start(void (*funct)(), uint64_t period_us) {
  // Teensy 3 at a 60 MHz bus: fewer than 36 cycles or more than ~71.5 s is refused.
  if (period_us == 0 || period_us > 71'000'000) return false;
  Timer& t = st().timers[static_cast<std::size_t>(id_)];
  t.running = true;
  t.funct = funct;
  t.period_us = period_us;
  t.next_us = st().now_us + period_us;
  st().last_period_us = period_us;
  st().last_priority = t.priority;
  return true;
}
bool IntervalTimer::begin(void (*funct)(), unsigned int us) { return start(funct, us); }
bool IntervalTimer::begin(void (*funct)(), int us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
bool IntervalTimer::begin(void (*funct)(), unsigned long us) { return start(funct, us); }
bool IntervalTimer::begin(void (*funct)(), long us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
bool IntervalTimer::begin(void (*funct)(), float us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
bool IntervalTimer::begin(void (*funct)(), double us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
void IntervalTimer::end() { st().timers[static_cast<std::size_t>(id_)].running = false; }
void IntervalTimer::priority(uint8_t n) { st().timers[static_cast<std::size_t>(id_)].priority = n; }

namespace fake {

void set_time_us(uint64_t t_us) {
  st().now_us = t_us;
  fake_arm_dwt_cyccnt = static_cast<uint32_t>(t_us * (kCpuHz / 1'000'000));
}
uint64_t time_us() { return st().now_us; }

void advance_us(uint64_t d_us) {
  State& s = st();
  const uint64_t target = s.now_us + d_us;
  for (;;) {
    Timer* due = nullptr;
    for (Timer& t : s.timers) {
      if (t.running && t.next_us <= target && (due == nullptr || t.next_us < due->next_us)) due = &t;
    }
    if (due == nullptr) break;
    set_time_us(due->next_us);
    due->next_us += due->period_us;  // periodic until end()
    due->funct();
  }
  set_time_us(target);
}

int pin_mode(uint8_t pin) { return st().pins[pin].mode; }
bool pin_level(uint8_t pin) { return st().pins[pin].level; }
uint32_t pin_writes(uint8_t pin) { return st().pins[pin].writes; }
void set_input(uint8_t pin, bool high) {
  Pin& p = st().pins[pin];
  if (p.level == high) return;
  p.level = high;
  if (p.isr != nullptr) p.isr();
}
bool interrupt_attached(uint8_t pin) { return st().pins[pin].isr != nullptr; }

void wire_script(uint8_t end_code, std::vector<uint8_t> data, std::size_t deliver) {
  st().end_code = end_code;
  st().read_data = std::move(data);
  st().deliver = deliver;
}
const std::vector<WireCall>& wire_calls() { return st().calls; }
uint32_t wire_clock_hz() { return st().wire_clock_hz; }

int timers_running() {
  const auto running = [](const Timer& t) { return t.running; };
  return static_cast<int>(std::count_if(st().timers.begin(), st().timers.end(), running));
}
uint64_t last_timer_period_us() { return st().last_period_us; }
uint8_t last_timer_priority() { return st().last_priority; }

void serial_set_connected(bool up) { st().connected = up; }
void serial_set_room(int bytes) { st().room = bytes; }
void serial_push_rx(const std::vector<uint8_t>& bytes) {
  st().serial_rx.insert(st().serial_rx.end(), bytes.begin(), bytes.end());
}
std::vector<uint8_t>& serial_tx() { return st().serial_tx; }
uint32_t serial_send_now_calls() { return st().send_now_calls; }

void rtc_set_raw(unsigned long s) { st().rtc_s = s; }

void reset() {
  State& s = st();
  std::vector<Timer> timers(s.timers.size());  // IntervalTimer objects keep their ids
  s = State{};
  s.timers = std::move(timers);
  set_time_us(0);
}

}  // namespace fake
