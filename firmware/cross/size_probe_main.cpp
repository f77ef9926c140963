// Composition root of the bare-metal cross image: the whole core (App and everything it
// owns) on stub HAL objects in static storage, begin() once and poll() in a loop, so the
// linker keeps every part of the core a real board would. build.sh measures this image
// against the flash/RAM budgets and checks it for heap use.
//
// Under QEMU (mps2-an386 / mps2-an500) it also proves the core boots: the stub link feeds
// one PING and decodes what the App sends; after 2.5 s of device time the image exits
// through semihosting with 0 if HELLO, two STATUS and the PING's ACK arrived intact.
// Time comes from the MPS2's CMSDK timer 0 (25 MHz); the alarm is polled from the loop
// (this image installs no interrupt handlers), which is all a boot check needs.
#include <cstddef>
#include <cstdint>

#include "core/app.hpp"
#include "cross_runtime.hpp"
#include "frame.hpp"

namespace {

namespace hal = icgt::hal;
namespace proto = icgt::proto;

constexpr uint64_t kRunUs = 2'500'000;
// Safety net if the timer does not run (wrong machine): give up rather than spin forever.
constexpr uint32_t kMaxPolls = 20'000'000;
constexpr uint32_t kPingNonce = 0x1C67;

struct CmsdkTimer {
  volatile uint32_t ctrl;
  volatile uint32_t value;
  volatile uint32_t reload;
  volatile uint32_t intstatus;
};

CmsdkTimer& timer0() { return *reinterpret_cast<CmsdkTimer*>(0x4000'0000u); }

class ProbeClock final : public hal::Clock {
 public:
  void begin() {
    timer0().reload = 0xFFFF'FFFFu;
    timer0().value = 0xFFFF'FFFFu;
    timer0().ctrl = 1;  // enable, no interrupt
  }
  // Only the loop reads this clock (no interrupts here), so a plain wrap count is enough.
  [[nodiscard]] uint64_t now_us() const override {
    const uint32_t ticks = 0xFFFF'FFFFu - timer0().value;  // a down-counter
    if (ticks < last_ticks_) wraps_ += 1;
    last_ticks_ = ticks;
    return ((uint64_t{wraps_} << 32) | ticks) / 25;
  }

 private:
  mutable uint32_t last_ticks_ = 0;
  mutable uint32_t wraps_ = 0;
};

class ProbeAlarm final : public hal::Alarm {
 public:
  void set_handler(Handler handler, void* ctx) override {
    handler_ = handler;
    ctx_ = ctx;
  }
  void arm_at(uint64_t t_us) override {
    deadline_us_ = t_us;
    armed_ = true;
  }
  void cancel() override { armed_ = false; }
  // Stands in for the timer interrupt.
  void service(uint64_t now_us) {
    if (!armed_ || now_us < deadline_us_) return;
    armed_ = false;
    if (handler_ != nullptr) handler_(ctx_, now_us);
  }

 private:
  Handler handler_ = nullptr;
  void* ctx_ = nullptr;
  uint64_t deadline_us_ = 0;
  bool armed_ = false;
};

// No sensors on the bus: every transfer is refused at the address, as with nothing plugged in.
class ProbeI2c final : public hal::I2cBus {
 public:
  [[nodiscard]] hal::I2cStatus transfer(uint8_t, const uint8_t*, std::size_t, uint8_t*, std::size_t,
                                        hal::I2cJoin) override {
    return hal::I2cStatus::nack_address;
  }
};

class ProbeOut final : public hal::DigitalOut {
 public:
  void write(bool high) override { level_ = high; }

 private:
  volatile bool level_ = false;
};

class ProbeEdge final : public hal::EdgeInput {
 public:
  [[nodiscard]] bool attach(Handler handler, void* ctx) override {
    handler_ = handler;
    ctx_ = ctx;
    return true;
  }
  void detach() override { handler_ = nullptr; }
  [[nodiscard]] bool read() const override { return false; }

 private:
  Handler handler_ = nullptr;
  void* ctx_ = nullptr;
};

class ProbeRtc final : public hal::Rtc {
 public:
  [[nodiscard]] bool get_utc_s(int64_t& utc_s) const override {
    utc_s = utc_s_;
    return utc_s_ != 0;
  }
  [[nodiscard]] bool set_utc_s(int64_t utc_s) override {
    utc_s_ = utc_s;
    return true;
  }

 private:
  int64_t utc_s_ = 0;
};

// The host end of the link: offers one PING frame, decodes everything the App writes.
class ProbeLink final : public hal::ByteStream {
 public:
  void begin() { command_len_ = proto::encode_message(ping(), 1, 0, command_, sizeof command_); }

  [[nodiscard]] std::size_t write(const uint8_t* data, std::size_t len) override {
    for (std::size_t i = 0; i < len; ++i) {
      if (decoder_.push(data[i]) != proto::StreamDecoder::Status::frame) continue;
      proto::Ack ack;
      if (decoder_.header().type == static_cast<uint8_t>(proto::MsgId::HELLO)) ++hello_;
      if (decoder_.header().type == static_cast<uint8_t>(proto::MsgId::STATUS)) ++status_;
      if (decoder_.decode(ack) && ack.detail == kPingNonce) ++ping_acks_;
    }
    return len;
  }
  [[nodiscard]] std::size_t writable() const override { return 512; }
  [[nodiscard]] std::size_t read(uint8_t* out, std::size_t cap) override {
    std::size_t n = 0;
    while (n < cap && sent_ < command_len_) out[n++] = command_[sent_++];
    return n;
  }
  [[nodiscard]] bool connected() const override { return true; }

  [[nodiscard]] bool passed() const {
    return hello_ == 1 && status_ >= 2 && ping_acks_ == 1 && decoder_.stats().rejected() == 0;
  }
  void report() const {
    icgt::cross::write("HELLO ");
    icgt::cross::write_u32(hello_);
    icgt::cross::write(", STATUS ");
    icgt::cross::write_u32(status_);
    icgt::cross::write(", PING ACK ");
    icgt::cross::write_u32(ping_acks_);
    icgt::cross::write(", frames rejected ");
    icgt::cross::write_u32(decoder_.stats().rejected());
    icgt::cross::write("\n");
  }

 private:
  static proto::Ping ping() {
    proto::Ping p;
    p.nonce = kPingNonce;
    return p;
  }

  uint8_t command_[proto::kMaxWireBytes]{};
  std::size_t command_len_ = 0;
  std::size_t sent_ = 0;
  proto::StreamDecoder decoder_;
  uint32_t hello_ = 0;
  uint32_t status_ = 0;
  uint32_t ping_acks_ = 0;
};

ProbeClock g_clock;
ProbeLink g_link;
ProbeI2c g_i2c;
ProbeAlarm g_alarm;
ProbeOut g_shutter;
ProbeOut g_focus;
ProbeEdge g_feedback;
ProbeEdge g_pps;
ProbeRtc g_rtc;

const icgt::core::AppPorts kPorts{g_clock, g_link, g_i2c, g_alarm, g_shutter, g_focus, &g_feedback, &g_pps, g_rtc};
const icgt::core::BoardIdentity kIdentity{proto::Board::qemu_mps2, 0, "size-probe"};

icgt::core::App g_app(kPorts, kIdentity);

}  // namespace

int main() {
  g_clock.begin();
  g_link.begin();
  g_app.begin();
  uint32_t polls = 0;
  while (g_clock.now_us() < kRunUs && polls < kMaxPolls) {
    g_app.poll();
    g_alarm.service(g_clock.now_us());
    ++polls;
  }
  icgt::cross::write("size probe: ");
  icgt::cross::write_u32(polls);
  icgt::cross::write(" polls in ");
  icgt::cross::write_u32(static_cast<uint32_t>(g_clock.now_us() / 1000));
  icgt::cross::write(" ms; stack used ");
  icgt::cross::write_u32(static_cast<uint32_t>(icgt::cross::stack_used_bytes()));
  icgt::cross::write(" bytes; ");
  g_link.report();
  return g_link.passed() && polls < kMaxPolls ? 0 : 1;
}
