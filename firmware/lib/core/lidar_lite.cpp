#include "core/lidar_lite.hpp"

namespace icgt::core {
namespace {

constexpr uint8_t kRegAcqCommand = 0x00;
constexpr uint8_t kRegStatus = 0x01;
constexpr uint8_t kRegSignalStrength = 0x0E;
constexpr uint8_t kRegDistanceHigh = 0x0F;
constexpr uint8_t kRegUnitIdHigh = 0x16;
// Legacy v3 only auto-increments when bit 7 of the pointer is set; v3HP always does.
constexpr uint8_t kAutoIncrement = 0x80;

constexpr uint8_t kCmdReset = 0x00;
constexpr uint8_t kCmdV3hpAcquire = 0x01;
constexpr uint8_t kCmdV3AcquireNoBias = 0x03;
constexpr uint8_t kCmdV3AcquireBias = 0x04;

constexpr uint8_t kStatusBusy = 0x01;
constexpr uint8_t kStatusNoSignal = 0x08;

constexpr uint8_t kDefaultAddr7 = 0x62;
// Garmin paces configure() writes with delay(1) on v3 and 100 us on v3HP; nothing says the
// part needs less, so the same spacing is kept.
constexpr uint32_t kV3WriteGap_us = 1'000;
constexpr uint32_t kV3hpWriteGap_us = 100;
// Between reset-wait probes: the part NACKs until it has reloaded, no point hammering it.
constexpr uint32_t kResetProbeInterval_us = 1'000;
constexpr uint8_t kMaxBackoffShift = 6;  // 20 ms << 6 > 1 s: the cap takes over

// Garmin configure(cfg) tables (sensors.md §2.1 and §2.3), in the vendor's write order.
constexpr uint8_t kV3Regs[3] = {0x02, 0x04, 0x1C};
constexpr uint8_t kV3Presets[limits::kLidarV3Presets][3] = {
    {0x80, 0x08, 0x00}, {0x1D, 0x08, 0x00}, {0x80, 0x00, 0x00},
    {0xFF, 0x08, 0x00}, {0x80, 0x08, 0x80}, {0x80, 0x08, 0xB0},
};
constexpr uint8_t kV3hpRegs[4] = {0x02, 0x04, 0x12, 0x1C};
constexpr uint8_t kV3hpPresets[limits::kLidarV3hpPresets][4] = {
    {0x80, 0x08, 0x05, 0x00}, {0x1D, 0x08, 0x03, 0x00}, {0x80, 0x00, 0x03, 0x00}, {0xFF, 0x08, 0x05, 0x00},
    {0x80, 0x08, 0x05, 0x80}, {0x80, 0x08, 0x05, 0xB0}, {0x04, 0x01, 0x03, 0x00},
};

constexpr bool is_v3hp(const LidarLiteConfig& c) { return c.model == LidarModelKind::v3hp; }
constexpr uint8_t preset_count(const LidarLiteConfig& c) {
  return is_v3hp(c) ? limits::kLidarV3hpPresets : limits::kLidarV3Presets;
}
constexpr uint8_t preset_len(const LidarLiteConfig& c) { return is_v3hp(c) ? 4 : 3; }

// Garmin's figures at SIG_COUNT_VAL 0x80 (v3 manual: 270 Hz typical; v3HP manual: > 1 kHz),
// scaled with the count as 1/4 fixed + 3/4 proportional, which also gives the v3 manual's
// 650 Hz "fast mode" at preset 1 (0x1D).
constexpr uint32_t kV3ConversionUs = 3'700;
constexpr uint32_t kV3hpConversionUs = 950;

uint32_t backoff_us(uint8_t failures_in_row) {
  const uint8_t shift = failures_in_row == 0 ? 0 : failures_in_row - 1;
  const uint64_t t = static_cast<uint64_t>(LidarLite::kBackoffMin_us) << (shift > kMaxBackoffShift ? kMaxBackoffShift : shift);
  return t > LidarLite::kBackoffMax_us ? LidarLite::kBackoffMax_us : static_cast<uint32_t>(t);
}

}  // namespace

LidarLite::LidarLite(hal::I2cBus& bus, const hal::Clock& clock, const LidarLiteConfig& config)
    : bus_(bus), clock_(clock), cfg_(config) {
  if (valid(config)) {
    period_us_ = 1'000'000u / config.rate_hz;
    state_ = LidarState::absent;
    phase_ = Phase::probe;
  }
}

uint32_t LidarLite::expected_conversion_us(const LidarLiteConfig& c) {
  if (!valid(c)) return kPollInterval_us;
  const uint32_t base = is_v3hp(c) ? kV3hpConversionUs : kV3ConversionUs;
  const uint32_t count = is_v3hp(c) ? kV3hpPresets[c.preset][0] : kV3Presets[c.preset][0];
  return base / 4 + (base * 3 / 4) * count / 0x80;
}

uint16_t LidarLite::max_rate_hz(const LidarLiteConfig& c) {
  const uint32_t hz = 1'000'000u / (expected_conversion_us(c) + kPollInterval_us);
  return static_cast<uint16_t>(hz > kMaxRate_hz ? kMaxRate_hz : hz);
}

bool LidarLite::valid(const LidarLiteConfig& c) {
  if (c.model != LidarModelKind::v3 && c.model != LidarModelKind::v3hp) return false;
  if (c.addr7 > 0x77 || c.addr7 < 0x08) return false;  // reserved I2C addresses
  return c.preset < preset_count(c) && c.rate_hz >= 1 && c.rate_hz <= kMaxRate_hz && c.bias_every >= 1;
}

bool LidarLite::reconfigure(const LidarLiteConfig& config) {
  if (!valid(config)) return false;
  cfg_ = config;
  period_us_ = 1'000'000u / config.rate_hz;
  start_over();
  return true;
}

void LidarLite::start_over() {
  // A part that was answering is assumed still there: reporting it absent for the one step
  // until the probe would flicker the health flags for nothing.
  state_ = present() ? LidarState::configuring : LidarState::absent;
  phase_ = Phase::probe;
  next_t_us_ = 0;
  failures_in_row_ = 0;
}

hal::I2cStatus LidarLite::write_reg(uint8_t reg, uint8_t value) {
  const uint8_t buf[2] = {reg, value};
  return bus_.transfer(cfg_.addr7, buf, 2, nullptr, 0, hal::I2cJoin::stop);
}

hal::I2cStatus LidarLite::read_regs(uint8_t reg, uint8_t* out, uint8_t n) {
  // Garmin's v3 guidelines want a STOP between pointer and data; the v3HP library uses a
  // repeated start. Each variant gets the framing its vendor code was tested with.
  const hal::I2cJoin join = is_v3hp(cfg_) ? hal::I2cJoin::repeated_start : hal::I2cJoin::stop;
  if (!is_v3hp(cfg_) && n > 1) reg |= kAutoIncrement;
  return bus_.transfer(cfg_.addr7, &reg, 1, out, n, join);
}

LidarStep LidarLite::step(uint64_t now_us) {
  switch (phase_) {
    case Phase::off:
      return LidarStep::idle;
    case Phase::probe:
      if (now_us < next_t_us_) return state_ == LidarState::configuring ? LidarStep::busy : LidarStep::idle;
      return do_probe(now_us);
    case Phase::reset: {
      if (write_reg(kRegAcqCommand, kCmdReset) != hal::I2cStatus::ok) {
        ++i2c_errors_;
        back_off(now_us);
        return LidarStep::error;
      }
      const uint64_t t = clock_.now_us();
      next_t_us_ = t + kResetWait_us;
      deadline_t_us_ = t + kResetDeadline_us;
      phase_ = Phase::reset_wait;
      return LidarStep::busy;
    }
    case Phase::reset_wait:
      if (now_us < next_t_us_) return LidarStep::busy;
      return do_reset_wait(now_us);
    case Phase::configure: {
      if (now_us < next_t_us_) return LidarStep::busy;
      const uint8_t i = config_index_;
      const hal::I2cStatus st = is_v3hp(cfg_) ? write_reg(kV3hpRegs[i], kV3hpPresets[cfg_.preset][i])
                                              : write_reg(kV3Regs[i], kV3Presets[cfg_.preset][i]);
      if (st != hal::I2cStatus::ok) {
        ++i2c_errors_;
        back_off(now_us);
        return LidarStep::error;
      }
      next_t_us_ = now_us + (is_v3hp(cfg_) ? kV3hpWriteGap_us : kV3WriteGap_us);
      if (++config_index_ < preset_len(cfg_)) return LidarStep::busy;
      state_ = LidarState::running;
      phase_ = Phase::wait_next;
      next_acq_t_us_ = next_t_us_;
      acquisitions_ = 0;  // the first acquisition after a (re)configuration is bias-corrected
      failures_in_row_ = 0;
      if (recovering_) ++reinits_;
      recovering_ = false;
      configured_once_ = true;
      return LidarStep::busy;
    }
    case Phase::wait_next:
      if (now_us < next_acq_t_us_) return LidarStep::idle;
      return do_acquire(now_us);
    case Phase::poll:
      if (now_us < next_t_us_) return LidarStep::busy;
      return do_poll(now_us);
    case Phase::read_distance:
      return do_read_distance(now_us);
    case Phase::read_signal:
      return do_read_signal(now_us);
  }
  return LidarStep::idle;
}

LidarStep LidarLite::do_probe(uint64_t now_us) {
  uint8_t id[2] = {0, 0};
  const hal::I2cStatus st = read_regs(kRegUnitIdHigh, id, 2);
  const uint16_t unit_id = static_cast<uint16_t>((id[0] << 8) | id[1]);
  // A zero UNIT_ID means something else answers at this address (0x62 is also a common
  // DAC / CO2 sensor address): ranging it would be meaningless.
  if (st != hal::I2cStatus::ok || unit_id == 0) {
    if (failures_in_row_ < 0xFF) ++failures_in_row_;
    state_ = LidarState::absent;
    next_t_us_ = now_us + backoff_us(failures_in_row_);
    return LidarStep::idle;
  }
  unit_id_ = unit_id;
  state_ = LidarState::configuring;
  config_index_ = 0;
  next_t_us_ = now_us;
  phase_ = cfg_.addr7 == kDefaultAddr7 ? Phase::reset : Phase::configure;
  return LidarStep::busy;
}

LidarStep LidarLite::do_reset_wait(uint64_t now_us) {
  uint8_t id[2] = {0, 0};
  if (read_regs(kRegUnitIdHigh, id, 2) == hal::I2cStatus::ok) {
    phase_ = Phase::configure;
    config_index_ = 0;
    next_t_us_ = now_us;
    return LidarStep::busy;
  }
  // NACKs are expected while the part reloads; only missing the deadline is a fault.
  if (now_us >= deadline_t_us_) {
    ++timeouts_;
    back_off(now_us);
    return LidarStep::error;
  }
  next_t_us_ = now_us + kResetProbeInterval_us;
  return LidarStep::busy;
}

LidarStep LidarLite::do_acquire(uint64_t now_us) {
  uint8_t cmd = kCmdV3hpAcquire;
  if (!is_v3hp(cfg_)) cmd = (acquisitions_ % cfg_.bias_every == 0) ? kCmdV3AcquireBias : kCmdV3AcquireNoBias;
  if (write_reg(kRegAcqCommand, cmd) != hal::I2cStatus::ok) {
    ++i2c_errors_;
    back_off(now_us);
    return LidarStep::error;
  }
  // The laser fires when the command lands, so this is the measurement instant (to within
  // the conversion time); the loop's now_us may be stale by the transfer itself.
  const uint64_t t = clock_.now_us();
  current_ = RangeSample{};
  current_.acq_start_t_us = t;
  current_.bias_corrected = cmd == kCmdV3AcquireBias;
  ++acquisitions_;
  // On the asked grid (a late start does not push every later one back, which would lose
  // rate to the loop's jitter); after a gap of more than a period, from now.
  next_acq_t_us_ = next_acq_t_us_ + period_us_ > t ? next_acq_t_us_ + period_us_ : t + period_us_;
  deadline_t_us_ = t + kBusyTimeout_us;
  // The first STATUS poll when the part should be done (Garmin's acquisition time for the
  // preset), then every 200 us rather than back to back (as the vendor does): polling from
  // the start took ~18 transfers per 3.7 ms v3 acquisition, over half the loop's time on a
  // 400 kHz bus. The sample's time is the acquisition start, so the read latency (<= 200 us
  // past the end) does not matter.
  next_t_us_ = t + expected_conversion_us(cfg_);
  phase_ = Phase::poll;
  return LidarStep::busy;
}

LidarStep LidarLite::do_poll(uint64_t now_us) {
  uint8_t status = 0;
  if (read_regs(kRegStatus, &status, 1) != hal::I2cStatus::ok) return fail_acquisition(now_us, false);
  if ((status & kStatusBusy) != 0) {
    if (now_us >= deadline_t_us_) return fail_acquisition(now_us, true);
    next_t_us_ = now_us + kPollInterval_us;
    return LidarStep::busy;
  }
  status_ = status;
  phase_ = Phase::read_distance;
  return LidarStep::busy;
}

LidarStep LidarLite::do_read_distance(uint64_t now_us) {
  uint8_t d[2] = {0, 0};
  if (read_regs(kRegDistanceHigh, d, 2) != hal::I2cStatus::ok) return fail_acquisition(now_us, false);
  current_.read_t_us = clock_.now_us();
  const uint16_t distance_cm = static_cast<uint16_t>((d[0] << 8) | d[1]);
  current_.no_signal = (status_ & kStatusNoSignal) != 0 || distance_cm <= 1;
  current_.valid = !current_.no_signal;
  current_.distance_cm = current_.valid ? distance_cm : 0;
  if (cfg_.read_signal_strength) {
    phase_ = Phase::read_signal;
    return LidarStep::busy;
  }
  return publish();
}

LidarStep LidarLite::do_read_signal(uint64_t now_us) {
  uint8_t s = 0;
  if (read_regs(kRegSignalStrength, &s, 1) != hal::I2cStatus::ok) {
    // The distance is already good; keep it and flag the failed read.
    current_.i2c_error = true;
    ++i2c_errors_;
    const LidarStep r = publish();
    back_off(now_us);
    return r;
  }
  current_.signal_strength = s;
  return publish();
}

LidarStep LidarLite::publish() {
  sample_ = current_;
  ++samples_;
  phase_ = Phase::wait_next;
  return LidarStep::sample_ready;
}

LidarStep LidarLite::fail_acquisition(uint64_t now_us, bool timed_out) {
  current_.read_t_us = clock_.now_us();
  current_.valid = false;
  current_.no_signal = false;
  current_.distance_cm = 0;
  current_.timeout = timed_out;
  current_.i2c_error = !timed_out;
  if (timed_out) {
    ++timeouts_;
  } else {
    ++i2c_errors_;
  }
  const LidarStep r = publish();
  back_off(now_us);
  return r;
}

void LidarLite::back_off(uint64_t now_us) {
  if (failures_in_row_ < 0xFF) ++failures_in_row_;
  recovering_ = configured_once_;
  state_ = LidarState::backing_off;
  phase_ = Phase::probe;
  next_t_us_ = now_us + backoff_us(failures_in_row_);
}

}  // namespace icgt::core
