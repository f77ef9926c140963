// Behaviour of the fake Teensyduino API: a deterministic, single-threaded model good enough to
// run the board layer and the composition root on the host, with each core's interrupt
// priorities, Wire codes, Serial results and RTC quirks (fake_control.h lists them). State
// lives in function-local statics so the static constructors of main.cpp may call in before
// main().
#include <algorithm>
#include <array>
#include <cstring>
#include <map>

#include "Arduino.h"
#include "IntervalTimer.h"
#include "Wire.h"
#include "fake_control.h"

namespace {

#if defined(__IMXRT1062__)
constexpr bool kTeensy4 = true;
constexpr int kUsbIrq = IRQ_USB1;
constexpr uint8_t kUsbPriority = 128;
#else
constexpr bool kTeensy4 = false;
constexpr int kUsbIrq = IRQ_USBOTG;
constexpr uint8_t kUsbPriority = 112;
#endif
constexpr int kNumIrqs = 256;
constexpr int kPitChannels = 4;
constexpr uint32_t kCoreStaleFlag = 0x5A94C3A5;  // teensy3/mk20dx128.c's VBAT word 7 value

struct Pin {
  int mode = -1;
  bool level = false;
  uint32_t writes = 0;
  int write_priority = fake::kThreadPriority;
  void (*isr)() = nullptr;
};

struct Channel {
  const IntervalTimer* owner = nullptr;
  bool running = false;
  void (*funct)() = nullptr;
  uint64_t period_us = 0;
  uint64_t next_us = 0;
};

struct State {
  uint64_t now_us = 0;
  uint64_t cycle_offset = 0;
  uint32_t micros_step_us = 0;
  bool stepping = false;
  std::array<uint8_t, kNumIrqs> nvic{};
  std::vector<int> active_irqs;
  int cyccnt_priority = fake::kThreadPriority;
  uint64_t cyccnt_cycles = 0;
  std::map<uint8_t, Pin> pins;
  std::array<Channel, kPitChannels> channels{};
  std::array<uint8_t, kPitChannels> t4_channel_priority{255, 255, 255, 255};  // teensy4 nvic_priorites[]
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
  fake::WireFault fault = fake::WireFault::none;
  // Serial
  bool connected = false;
  int room = 4096;
  bool fail_writes = false;
  std::vector<uint8_t> serial_rx;
  std::size_t serial_rx_pos = 0;
  std::vector<uint8_t> serial_tx;
  uint32_t send_now_calls = 0;
  // RTC: seconds = base + now / 1 s; Teensy 4 shows the previous base until the resync.
  unsigned long rtc_base_s = 0;
  unsigned long rtc_prev_base_s = 0;
  uint64_t rtc_set_at_us = 0;
  bool rtc_syncing = false;
  uint64_t rtc_sync_delay_us = 92;
};

State& st() {
  static State s = [] {
    State init;
    init.nvic.fill(128);
    init.nvic[kUsbIrq] = kUsbPriority;
    return init;
  }();
  return s;
}

void run_irq(int irq, void (*fn)()) {
  st().active_irqs.push_back(irq);
  fn();
  st().active_irqs.pop_back();
}

int pit_irq_of(int channel) {
#if defined(__IMXRT1062__)
  (void)channel;
  return IRQ_PIT;
#else
  return IRQ_PIT_CH0 + channel;
#endif
}

void t4_update_pit_priority() {
#if defined(__IMXRT1062__)
  uint8_t top = 255;
  for (uint8_t p : st().t4_channel_priority) top = std::min(top, p);
  st().nvic[IRQ_PIT] = top;
#endif
}

#if !defined(__IMXRT1062__)
bool cycle_counter_enabled() {
  return (fake_arm_demcr & ARM_DEMCR_TRCENA) != 0 && (fake_arm_dwt_ctrl & ARM_DWT_CTRL_CYCCNTENA) != 0;
}
#endif

unsigned long rtc_now_s(unsigned long base) { return base + static_cast<unsigned long>(st().now_us / 1'000'000); }

}  // namespace

#if defined(__IMXRT1062__)
volatile uint32_t F_CPU_ACTUAL = fake::kCpuHz;
volatile uint32_t fake_snvs_lpgpr[4] = {};
#else
volatile uint32_t fake_arm_demcr = 0;
volatile uint32_t fake_arm_dwt_ctrl = 0;
volatile uint32_t fake_vbat_register_file[8] = {};
const volatile uint32_t* fake_port_config_register(uint8_t pin) {
  // Teensy 3.6 pins (teensy3/core_pins.h CORE_PINn_CONFIG): 2 PTD0, 3 PTA12, 4 PTA13, 5 PTD7,
  // 40 PTA28; others are put on port E here. Port x's PCRn is at 0x40049000 + x * 0x1000 + 4n.
  uintptr_t port = 4, n = 0;
  switch (pin) {
    case 2: port = 3, n = 0; break;
    case 3: port = 0, n = 12; break;
    case 4: port = 0, n = 13; break;
    case 5: port = 3, n = 7; break;
    case 40: port = 0, n = 28; break;
    default: break;
  }
  return reinterpret_cast<const volatile uint32_t*>(0x4004'9000u + port * 0x1000u + 4u * n);
}
#endif

usb_serial_class Serial;
teensy3_clock_class Teensy3Clock;
TwoWire Wire;

uint32_t micros() {
  State& s = st();
  if (s.micros_step_us > 0 && !s.stepping) {
    s.stepping = true;
    fake::advance_us(s.micros_step_us);
    s.stepping = false;
  }
  return static_cast<uint32_t>(s.now_us);
}
uint32_t millis() { return static_cast<uint32_t>(st().now_us / 1000); }
void pinMode(uint8_t pin, uint8_t mode) { st().pins[pin].mode = mode; }
void digitalWriteFast(uint8_t pin, uint8_t val) {
  Pin& p = st().pins[pin];
  p.level = val != 0;
  ++p.writes;
  p.write_priority = fake::execution_priority();
}
uint8_t digitalReadFast(uint8_t pin) { return st().pins[pin].level ? 1 : 0; }
void attachInterrupt(uint8_t pin, void (*function)(void), int mode) {
  if (mode == CHANGE) st().pins[pin].isr = function;
}
void detachInterrupt(uint8_t pin) { st().pins[pin].isr = nullptr; }
void noInterrupts() {}
void interrupts() {}

void fake_nvic_set_priority(int irq, uint8_t priority) {
  if (irq >= 0 && irq < kNumIrqs) st().nvic[static_cast<std::size_t>(irq)] = priority;
}

uint32_t fake_read_cyccnt() {
  State& s = st();
  s.cyccnt_priority = fake::execution_priority();
#if !defined(__IMXRT1062__)
  if (!cycle_counter_enabled()) return 0;  // DWT off: the counter does not run
#endif
  s.cyccnt_cycles = fake::cycles();
  return static_cast<uint32_t>(s.cyccnt_cycles);
}

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
  if (!s.connected || s.fail_writes) {
    // Teensy 3: usb_serial_write() returns int -1, handed on as size_t. Teensy 4: 0.
    return kTeensy4 ? 0 : static_cast<size_t>(-1);
  }
  s.serial_tx.insert(s.serial_tx.end(), buffer, buffer + size);
  return size;
}
void usb_serial_class::send_now() { ++st().send_now_calls; }
uint8_t usb_serial_class::dtr() { return st().connected ? 1 : 0; }
usb_serial_class::operator bool() { return st().connected; }

unsigned long teensy3_clock_class::get() {
  State& s = st();
  if (kTeensy4 && s.rtc_syncing) {
    if (s.rtc_sync_delay_us != UINT64_MAX && s.now_us >= s.rtc_set_at_us + s.rtc_sync_delay_us) {
      s.rtc_syncing = false;
    } else {
      return rtc_now_s(s.rtc_prev_base_s);
    }
  }
  return rtc_now_s(s.rtc_base_s);
}
void teensy3_clock_class::set(unsigned long t) {
  State& s = st();
  if (kTeensy4) {
    if (!s.rtc_syncing) s.rtc_prev_base_s = s.rtc_base_s;
    s.rtc_syncing = true;
    s.rtc_set_at_us = s.now_us;
  }
  s.rtc_base_s = t - static_cast<unsigned long>(s.now_us / 1'000'000);
}

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
  switch (s.fault) {
    case fake::WireFault::none: return s.end_code;
    case fake::WireFault::nack_address: return 2;
    case fake::WireFault::nack_data: return kTeensy4 ? 2 : (s.tx.empty() ? 2 : 3);
    case fake::WireFault::stuck_bus:
      fake::advance_us(fake::kStuckBusWaitUs);  // interrupts keep running meanwhile
      return 4;
    case fake::WireFault::fifo_error: return kTeensy4 ? 5 : 4;
  }
  return 4;
}
uint8_t TwoWire::endTransmission() { return endTransmission(1); }
uint8_t TwoWire::requestFrom(uint8_t address, uint8_t quantity, uint8_t sendStop) {
  State& s = st();
  s.calls.push_back({'r', address, quantity, sendStop});
  if (s.fault == fake::WireFault::stuck_bus) {
    fake::advance_us(fake::kStuckBusWaitUs);
    // Teensy 4 returns 4 before touching its receive buffer; Teensy 3 returns 0.
    if (kTeensy4) return 4;
    s.rx.clear();
    s.rx_pos = 0;
    return 0;
  }
  s.rx.clear();
  s.rx_pos = 0;
  if (s.fault != fake::WireFault::none) return 0;  // address NACK (and the rest): nothing received
  const std::size_t n = std::min<std::size_t>({quantity, s.deliver, s.read_data.size()});
  s.rx.assign(s.read_data.begin(), s.read_data.begin() + static_cast<long>(n));
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

IntervalTimer::IntervalTimer() = default;
// The real destructor calls end(); here the core state may already be gone at static destruction.
IntervalTimer::~IntervalTimer() = default;
bool IntervalTimer::start(void (*funct)(), uint64_t period_us) {
  // Teensy 3 at a 60 MHz bus: fewer than 36 cycles or more than ~71.5 s is refused.
  if (period_us == 0 || period_us > 71'000'000) return false;
  State& s = st();
  if (channel_ < 0 || s.channels[static_cast<std::size_t>(channel_)].owner != this) {
    channel_ = -1;
    for (int i = 0; i < kPitChannels; ++i) {
      if (s.channels[static_cast<std::size_t>(i)].owner == nullptr) {
        channel_ = i;
        break;
      }
    }
    if (channel_ < 0) return false;  // every channel taken
  }
  Channel& c = s.channels[static_cast<std::size_t>(channel_)];
  c.owner = this;
  c.running = true;
  c.funct = funct;
  c.period_us = period_us;
  c.next_us = s.now_us + period_us;
  if (kTeensy4) {
    s.t4_channel_priority[static_cast<std::size_t>(channel_)] = nvic_priority_;
    t4_update_pit_priority();
  } else {
    fake_nvic_set_priority(pit_irq_of(channel_), nvic_priority_);
  }
  s.last_period_us = period_us;
  s.last_priority = nvic_priority_;
  return true;
}
bool IntervalTimer::begin(void (*funct)(), unsigned int us) { return start(funct, us); }
bool IntervalTimer::begin(void (*funct)(), int us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
bool IntervalTimer::begin(void (*funct)(), unsigned long us) { return start(funct, us); }
bool IntervalTimer::begin(void (*funct)(), long us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
bool IntervalTimer::begin(void (*funct)(), float us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
bool IntervalTimer::begin(void (*funct)(), double us) { return us > 0 && start(funct, static_cast<uint64_t>(us)); }
void IntervalTimer::end() {
  State& s = st();
  if (channel_ < 0 || s.channels[static_cast<std::size_t>(channel_)].owner != this) {
    channel_ = -1;
    return;
  }
  s.channels[static_cast<std::size_t>(channel_)] = Channel{};
  if (kTeensy4) {
    s.t4_channel_priority[static_cast<std::size_t>(channel_)] = 255;
    t4_update_pit_priority();
  }
  channel_ = -1;
}
void IntervalTimer::priority(uint8_t n) {
  nvic_priority_ = n;
  State& s = st();
  if (channel_ < 0 || s.channels[static_cast<std::size_t>(channel_)].owner != this) return;
  if (kTeensy4) {
    s.t4_channel_priority[static_cast<std::size_t>(channel_)] = n;
    t4_update_pit_priority();
  } else {
    fake_nvic_set_priority(pit_irq_of(channel_), n);
  }
}

namespace fake {

void set_time_us(uint64_t t_us) { st().now_us = t_us; }
uint64_t time_us() { return st().now_us; }
void set_micros_step_us(uint32_t step_us) { st().micros_step_us = step_us; }
uint64_t cycles() { return st().now_us * (kCpuHz / 1'000'000) + st().cycle_offset; }
void set_cycle_offset(uint64_t offset) { st().cycle_offset = offset; }

void advance_us(uint64_t d_us) {
  State& s = st();
  const uint64_t target = s.now_us + d_us;
  for (;;) {
    int due = -1;
    for (int i = 0; i < kPitChannels; ++i) {
      const Channel& c = s.channels[static_cast<std::size_t>(i)];
      if (c.running && c.next_us <= target &&
          (due < 0 || c.next_us < s.channels[static_cast<std::size_t>(due)].next_us)) {
        due = i;
      }
    }
    if (due < 0) break;
    Channel& c = s.channels[static_cast<std::size_t>(due)];
    set_time_us(std::max(s.now_us, c.next_us));
    c.next_us += c.period_us;  // periodic until end()
    run_irq(pit_irq_of(due), c.funct);
  }
  set_time_us(std::max(s.now_us, target));
}

uint8_t nvic_priority(int irq) { return st().nvic[static_cast<std::size_t>(irq)]; }
int execution_priority() {
  int p = kThreadPriority;
  for (int irq : st().active_irqs) p = std::min<int>(p, st().nvic[static_cast<std::size_t>(irq)]);
  return p;
}
int usb_irq() { return kUsbIrq; }
int pit_irq(int channel) { return pit_irq_of(channel); }

int pin_mode(uint8_t pin) { return st().pins[pin].mode; }
bool pin_level(uint8_t pin) { return st().pins[pin].level; }
uint32_t pin_writes(uint8_t pin) { return st().pins[pin].writes; }
int pin_write_priority(uint8_t pin) { return st().pins[pin].write_priority; }
int pin_irq(uint8_t pin) {
#if defined(__IMXRT1062__)
  (void)pin;
  return IRQ_GPIO6789;
#else
  const auto pcr = reinterpret_cast<uintptr_t>(fake_port_config_register(pin));
  return IRQ_PORTA + static_cast<int>((pcr - 0x4004'9000u) >> 12);
#endif
}
void set_input(uint8_t pin, bool high) {
  Pin& p = st().pins[pin];
  if (p.level == high) return;
  p.level = high;
  if (p.isr != nullptr) run_irq(pin_irq(pin), p.isr);
}
bool interrupt_attached(uint8_t pin) { return st().pins[pin].isr != nullptr; }
int last_cyccnt_read_priority() { return st().cyccnt_priority; }
uint64_t last_cyccnt_read_cycles() { return st().cyccnt_cycles; }
void run_in_irq(int irq, void (*fn)(void*), void* ctx) {
  st().active_irqs.push_back(irq);
  fn(ctx);
  st().active_irqs.pop_back();
}

void wire_script(uint8_t end_code, std::vector<uint8_t> data, std::size_t deliver) {
  st().end_code = end_code;
  st().read_data = std::move(data);
  st().deliver = deliver;
}
void wire_fault(WireFault fault) { st().fault = fault; }
const std::vector<WireCall>& wire_calls() { return st().calls; }
uint32_t wire_clock_hz() { return st().wire_clock_hz; }

int timers_running() {
  const auto running = [](const Channel& c) { return c.running; };
  return static_cast<int>(std::count_if(st().channels.begin(), st().channels.end(), running));
}
uint64_t last_timer_period_us() { return st().last_period_us; }
uint8_t last_timer_priority() { return st().last_priority; }

void serial_set_connected(bool up) { st().connected = up; }
void serial_set_room(int bytes) { st().room = bytes; }
void serial_fail_writes(bool fail) { st().fail_writes = fail; }
void serial_push_rx(const std::vector<uint8_t>& bytes) {
  st().serial_rx.insert(st().serial_rx.end(), bytes.begin(), bytes.end());
}
std::vector<uint8_t>& serial_tx() { return st().serial_tx; }
uint32_t serial_send_now_calls() { return st().send_now_calls; }

void rtc_set_raw(unsigned long s) {
  st().rtc_base_s = s - static_cast<unsigned long>(st().now_us / 1'000'000);
  st().rtc_syncing = false;
}
unsigned long rtc_raw() { return rtc_now_s(st().rtc_base_s); }
void rtc_set_sync_delay_us(uint64_t delay_us) { st().rtc_sync_delay_us = delay_us; }

void rtc_vbat_power_up() {
#if defined(__IMXRT1062__)
  for (auto& w : fake_snvs_lpgpr) w = 0;
  rtc_set_raw(kTeensy4DefaultS);
#else
  for (auto& w : fake_vbat_register_file) w = 0;
  rtc_set_raw(kBuildTimeS);
  fake_vbat_register_file[7] = kCoreStaleFlag;
#endif
}

void rtc_upload(unsigned long loader_time_s) {
#if defined(__IMXRT1062__)
  if (loader_time_s != 0) rtc_set_raw(loader_time_s);
#else
  (void)loader_time_s;
  if (fake_vbat_register_file[7] == kCoreStaleFlag) {
    rtc_set_raw(kBuildTimeS);
    fake_vbat_register_file[7] = 0;
  }
#endif
}

void reset() {
  State& s = st();
  s = State{};
  s.nvic.fill(128);
  s.nvic[kUsbIrq] = kUsbPriority;
#if defined(__IMXRT1062__)
  for (auto& w : fake_snvs_lpgpr) w = 0;
#else
  for (auto& w : fake_vbat_register_file) w = 0;
  fake_arm_demcr = 0;
  fake_arm_dwt_ctrl = 0;
#endif
  set_time_us(0);
}

}  // namespace fake
