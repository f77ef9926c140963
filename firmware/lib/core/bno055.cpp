#include "core/bno055.hpp"

#include <cstddef>

#include "core/limits.hpp"

namespace icgt::core {

namespace {

constexpr uint8_t kRegChipId = 0x00;
constexpr uint8_t kRegPageId = 0x07;
constexpr uint8_t kRegAccData = 0x08;  // ACC, MAG, GYR: 0x08..0x19
constexpr uint8_t kRegQuaData = 0x20;  // QUA, LIA, GRV, TEMP, CALIB_STAT: 0x20..0x35
constexpr uint8_t kRegUnitSel = 0x3B;
constexpr uint8_t kRegOprMode = 0x3D;
constexpr uint8_t kRegPwrMode = 0x3E;
constexpr uint8_t kRegSysTrigger = 0x3F;

constexpr uint8_t kChipId = 0xA0;
constexpr uint8_t kModeConfig = 0x00;
constexpr uint8_t kModeMask = 0x0F;  // OPR_MODE has a reserved bit set at power-up (reads 0x10)
constexpr uint8_t kModeFirstFusion = limits::kImuFirstFusionMode;
constexpr uint8_t kModeLastFusion = limits::kImuLastFusionMode;
constexpr uint8_t kPwrModeNormal = 0x00;
constexpr uint8_t kSysTriggerRstSys = 0x20;
constexpr uint8_t kSysTriggerClkSel = 0x80;
constexpr uint8_t kUnitAccMg = 0x01;
constexpr uint8_t kUnitGyrRad = 0x02;
constexpr uint8_t kUnitTempF = 0x10;

// Both bursts stay within the Teensy Wire buffer (32 bytes); one 46-byte burst would not.
constexpr std::size_t kBurst1Len = 0x19 - kRegAccData + 1;
constexpr std::size_t kBurst2Len = 0x35 - kRegQuaData + 1;
static_assert(kBurst1Len == 18 && kBurst2Len == 22, "burst layout of the data registers");

// The vendor library allows 850 ms for the part to boot; the margin covers slow clones.
constexpr uint64_t kBootTimeoutUs = 1'000'000;
constexpr uint64_t kPollUs = 10'000;
// Datasheet: 19 ms into CONFIG, 7 ms out of it. The vendor library's 30 ms covers both.
constexpr uint64_t kModeSwitchUs = 30'000;
// The part NACKs for hundreds of ms after RST_SYS; start polling as the library does.
constexpr uint64_t kFirstResetPollUs = 30'000;
// The library waits 50 ms after the chip id returns before touching configuration.
constexpr uint64_t kAfterResetUs = 50'000;
constexpr uint64_t kRegisterSettleUs = 10'000;
constexpr uint64_t kBackoffMinUs = 100'000;
constexpr uint64_t kBackoffMaxUs = 5'000'000;

constexpr uint16_t kMaxRateHz = limits::kImuMaxRateHz;
constexpr float kPi = 3.14159265358979F;
constexpr float kQuatPerLsb = 1.0F / 16384.0F;
constexpr float kRadSPerLsbDps = kPi / (180.0F * 16.0F);
constexpr float kRadSPerLsbRad = 1.0F / 900.0F;
constexpr float kM_s2PerLsb = 1.0F / 100.0F;
constexpr float kM_s2PerMg = 9.80665F / 1000.0F;

[[nodiscard]] float le_i16(const uint8_t* p) {
  return static_cast<float>(static_cast<int16_t>(static_cast<uint16_t>(p[0] | (p[1] << 8))));
}

[[nodiscard]] bool fusion_mode(uint8_t mode) { return mode >= kModeFirstFusion && mode <= kModeLastFusion; }

[[nodiscard]] Bno055Config sanitised(Bno055Config c) {
  const Bno055Config defaults;
  if (c.addr7 != 0x28 && c.addr7 != 0x29) c.addr7 = defaults.addr7;
  if (!fusion_mode(c.opr_mode)) c.opr_mode = defaults.opr_mode;
  if (c.rate_hz == 0) c.rate_hz = 1;
  if (c.rate_hz > kMaxRateHz) c.rate_hz = kMaxRateHz;
  return c;
}

[[nodiscard]] uint64_t period_us(uint16_t rate_hz) { return 1'000'000U / rate_hz; }

}  // namespace

Bno055::Bno055(hal::I2cBus& bus, const hal::Clock& clock, const Bno055Config& config)
    : bus_(bus), clock_(clock), config_(sanitised(config)), backoff_us_(kBackoffMinUs) {
  period_us_ = period_us(config_.rate_hz);
}

bool Bno055::valid(const Bno055Config& config) {
  return (config.addr7 == 0x28 || config.addr7 == 0x29) && fusion_mode(config.opr_mode) && config.rate_hz >= 1 &&
         config.rate_hz <= kMaxRateHz;
}

bool Bno055::reconfigure(const Bno055Config& config) {
  if (!valid(config)) return false;
  const bool restart = config.addr7 != config_.addr7 || config.opr_mode != config_.opr_mode ||
                       config.ext_crystal != config_.ext_crystal;
  config_ = config;
  period_us_ = period_us(config_.rate_hz);
  if (restart) {
    phase_ = Phase::start;
    state_ = Bno055State::initialising;
    present_ = false;
    failed_present_ = false;
    backoff_us_ = kBackoffMinUs;
    not_before_t_us_ = 0;
  }
  return true;
}

Bno055Step Bno055::step(uint64_t now_us) {
  if (now_us < not_before_t_us_) return Bno055Step::idle;
  return step_phase(now_us);
}

Bno055Step Bno055::step_phase(uint64_t now_us) {
  hal::I2cDevice d = dev();
  switch (phase_) {
    case Phase::back_off:
    case Phase::start: {
      if (failed_present_ && reinits_ < UINT16_MAX) ++reinits_;
      failed_present_ = false;
      // Keep reporting absent while probing for a part that has not answered yet.
      if (state_ != Bno055State::absent) state_ = Bno055State::initialising;
      deadline_t_us_ = now_us + kBootTimeoutUs;
      phase_ = Phase::probe;
      [[fallthrough]];
    }
    case Phase::probe: {
      const hal::I2cStatus st = d.probe();
      if (st == hal::I2cStatus::ok) {
        present_ = true;
        state_ = Bno055State::initialising;
        phase_ = Phase::check_id;
        // The library re-reads a wrong id once after 1 s; poll it for as long instead.
        deadline_t_us_ = now_us + kBootTimeoutUs;
        not_before_t_us_ = now_us;
        return Bno055Step::busy;
      }
      if (st != hal::I2cStatus::nack_address && i2c_errors_ < UINT32_MAX) ++i2c_errors_;
      if (now_us >= deadline_t_us_) {
        present_ = false;
        return fail(now_us);
      }
      not_before_t_us_ = now_us + kPollUs;
      return Bno055Step::busy;
    }
    case Phase::check_id: {
      uint8_t id = 0;
      const hal::I2cStatus st = d.read_register(kRegChipId, id);
      if (st != hal::I2cStatus::ok) return fail_transfer(now_us);
      if (id == kChipId) {
        phase_ = Phase::enter_config;
        not_before_t_us_ = now_us;
        return Bno055Step::busy;
      }
      if (now_us >= deadline_t_us_) return fail(now_us);
      not_before_t_us_ = now_us + kPollUs;
      return Bno055Step::busy;
    }
    case Phase::enter_config:
      return write_then(kRegOprMode, kModeConfig, Phase::reset, kModeSwitchUs, now_us);
    case Phase::reset:
      deadline_t_us_ = now_us + kBootTimeoutUs;
      return write_then(kRegSysTrigger, kSysTriggerRstSys, Phase::wait_reset, kFirstResetPollUs, now_us);
    case Phase::wait_reset: {
      uint8_t id = 0;
      const hal::I2cStatus st = d.read_register(kRegChipId, id);
      if (st == hal::I2cStatus::ok && id == kChipId) {
        phase_ = Phase::power_mode;
        not_before_t_us_ = now_us + kAfterResetUs;
        return Bno055Step::busy;
      }
      if (st != hal::I2cStatus::ok && st != hal::I2cStatus::nack_address && i2c_errors_ < UINT32_MAX) {
        ++i2c_errors_;
      }
      if (now_us >= deadline_t_us_) return fail(now_us);
      not_before_t_us_ = now_us + kPollUs;
      return Bno055Step::busy;
    }
    case Phase::power_mode:
      return write_then(kRegPwrMode, kPwrModeNormal, Phase::page, kRegisterSettleUs, now_us);
    case Phase::page:
      return write_then(kRegPageId, 0, Phase::clock_select, 0, now_us);
    case Phase::clock_select:
      return write_then(kRegSysTrigger, config_.ext_crystal ? kSysTriggerClkSel : 0, Phase::read_units,
                        kRegisterSettleUs, now_us);
    case Phase::read_units: {
      // Decode with whatever units the part is set to rather than assuming the defaults.
      uint8_t units = 0;
      const hal::I2cStatus st = d.read_register(kRegUnitSel, units);
      if (st != hal::I2cStatus::ok) return fail_transfer(now_us);
      accel_mg_unit_ = (units & kUnitAccMg) != 0;
      gyro_rad_s_unit_ = (units & kUnitGyrRad) != 0;
      temp_f_unit_ = (units & kUnitTempF) != 0;
      phase_ = Phase::set_mode;
      not_before_t_us_ = now_us;
      return Bno055Step::busy;
    }
    case Phase::set_mode:
      return write_then(kRegOprMode, config_.opr_mode, Phase::verify_mode, kModeSwitchUs, now_us);
    case Phase::verify_mode: {
      uint8_t mode = 0;
      const hal::I2cStatus st = d.read_register(kRegOprMode, mode);
      if (st != hal::I2cStatus::ok) return fail_transfer(now_us);
      if ((mode & kModeMask) != config_.opr_mode) return fail(now_us);
      state_ = Bno055State::running;
      phase_ = Phase::read_data;
      first_sample_ = true;
      backoff_us_ = kBackoffMinUs;
      not_before_t_us_ = now_us;
      return Bno055Step::busy;
    }
    case Phase::read_data:
      return read_data(now_us);
    case Phase::confirm_reset: {
      uint8_t mode = 0;
      const hal::I2cStatus st = d.read_register(kRegOprMode, mode);
      if (st != hal::I2cStatus::ok) return fail_transfer(now_us);
      if ((mode & kModeMask) != config_.opr_mode) return fail(now_us);
      // Still in our mode: the zero quaternion was a glitch, not a reset. Drop that sample.
      phase_ = Phase::read_data;
      not_before_t_us_ = now_us + period_us_;
      return Bno055Step::busy;
    }
  }
  return Bno055Step::idle;
}

Bno055Step Bno055::read_data(uint64_t now_us) {
  hal::I2cDevice d = dev();
  uint8_t amg[kBurst1Len];
  uint8_t qlg[kBurst2Len];
  const uint64_t start_t_us = clock_.now_us();
  hal::I2cStatus st = d.read_registers(kRegAccData, amg, sizeof amg);
  if (st != hal::I2cStatus::ok) return fail_transfer(now_us);
  st = d.read_registers(kRegQuaData, qlg, sizeof qlg);
  if (st != hal::I2cStatus::ok) return fail_transfer(now_us);
  const uint64_t end_t_us = clock_.now_us();

  // A running fusion never outputs an all-zero quaternion; a part that reset itself sits in
  // CONFIG mode, where every data register reads zero. Confirm with OPR_MODE next step.
  bool quat_zero = true;
  for (std::size_t i = 0; i < 8; ++i) quat_zero = quat_zero && qlg[i] == 0;
  if (quat_zero) {
    phase_ = Phase::confirm_reset;
    not_before_t_us_ = now_us;
    return Bno055Step::busy;
  }

  decode(amg, qlg);
  sample_.read_start_t_us = start_t_us;
  sample_.read_end_t_us = end_t_us;
  sample_.reinitialised = first_sample_;
  first_sample_ = false;

  // Keep the cadence, but after a stall resynchronise instead of reading back-to-back.
  const uint64_t next_t_us = not_before_t_us_ + period_us_;
  not_before_t_us_ = next_t_us > now_us ? next_t_us : now_us + period_us_;
  return Bno055Step::sample_ready;
}

void Bno055::decode(const uint8_t* amg, const uint8_t* qlg) {
  const float acc_scale = accel_mg_unit_ ? kM_s2PerMg : kM_s2PerLsb;
  const float gyr_scale = gyro_rad_s_unit_ ? kRadSPerLsbRad : kRadSPerLsbDps;
  sample_.accel_x_m_s2 = le_i16(amg + 0) * acc_scale;
  sample_.accel_y_m_s2 = le_i16(amg + 2) * acc_scale;
  sample_.accel_z_m_s2 = le_i16(amg + 4) * acc_scale;
  sample_.gyro_x_rad_s = le_i16(amg + 12) * gyr_scale;
  sample_.gyro_y_rad_s = le_i16(amg + 14) * gyr_scale;
  sample_.gyro_z_rad_s = le_i16(amg + 16) * gyr_scale;
  sample_.quat_w = le_i16(qlg + 0) * kQuatPerLsb;
  sample_.quat_x = le_i16(qlg + 2) * kQuatPerLsb;
  sample_.quat_y = le_i16(qlg + 4) * kQuatPerLsb;
  sample_.quat_z = le_i16(qlg + 6) * kQuatPerLsb;
  sample_.lin_accel_x_m_s2 = le_i16(qlg + 8) * acc_scale;
  sample_.lin_accel_y_m_s2 = le_i16(qlg + 10) * acc_scale;
  sample_.lin_accel_z_m_s2 = le_i16(qlg + 12) * acc_scale;
  const int raw_temp = static_cast<int8_t>(qlg[20]);
  // Fahrenheit mode: 2 LSB per degree F.
  sample_.temp_c = temp_f_unit_ ? static_cast<int8_t>((raw_temp - 64) * 5 / 18) : static_cast<int8_t>(raw_temp);
  sample_.calib_stat = qlg[21];
}

Bno055Step Bno055::write_then(uint8_t reg, uint8_t value, Phase next, uint64_t wait_us, uint64_t now_us) {
  const hal::I2cStatus st = dev().write_register(reg, value);
  if (st != hal::I2cStatus::ok) return fail_transfer(now_us);
  phase_ = next;
  not_before_t_us_ = now_us + wait_us;
  return Bno055Step::busy;
}

Bno055Step Bno055::fail_transfer(uint64_t now_us) {
  if (i2c_errors_ < UINT32_MAX) ++i2c_errors_;
  return fail(now_us);
}

Bno055Step Bno055::fail(uint64_t now_us) {
  state_ = present_ ? Bno055State::backing_off : Bno055State::absent;
  failed_present_ = present_;
  phase_ = Phase::back_off;
  not_before_t_us_ = now_us + backoff_us_;
  backoff_us_ = backoff_us_ * 2 > kBackoffMaxUs ? kBackoffMaxUs : backoff_us_ * 2;
  return Bno055Step::error;
}

}  // namespace icgt::core
