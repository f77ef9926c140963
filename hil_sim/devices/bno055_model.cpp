#include "devices/bno055_model.hpp"

#include <algorithm>
#include <cmath>

namespace icgt::sim {

namespace {

constexpr uint8_t kRegChipId = 0x00;
constexpr uint8_t kRegPageId = 0x07;
constexpr uint8_t kRegDataFirst = 0x08;
constexpr uint8_t kRegDataLast = 0x35;
constexpr uint8_t kRegStResult = 0x36;
constexpr uint8_t kRegSysStatus = 0x39;
constexpr uint8_t kRegUnitSel = 0x3B;
constexpr uint8_t kRegOprMode = 0x3D;
constexpr uint8_t kRegPwrMode = 0x3E;
constexpr uint8_t kRegSysTrigger = 0x3F;
constexpr uint8_t kRegTempSource = 0x40;
constexpr uint8_t kRegAxisMapConfig = 0x41;
constexpr uint8_t kRegAxisMapSign = 0x42;
constexpr uint8_t kRegSicFirst = 0x43;
constexpr uint8_t kRegSicLast = 0x54;
constexpr uint8_t kRegOffsetFirst = 0x55;
constexpr uint8_t kRegOffsetLast = 0x6A;
constexpr uint8_t kPage1ConfigFirst = 0x08;  // ACC/MAG/GYR config, sleep, interrupt settings
constexpr uint8_t kPage1ConfigLast = 0x1F;

constexpr uint8_t kOprReservedBits = 0x10;  // observed at power-up: reads 0x10 in CONFIG
constexpr uint8_t kModeConfig = 0x00;
constexpr uint8_t kModeMax = 0x0C;
constexpr uint8_t kSysTriggerRstSys = 0x20;
constexpr uint8_t kSysTriggerClkSel = 0x80;
constexpr uint8_t kUnitSelDefinedBits = 0x97;  // bits 0, 1, 2, 4, 7
constexpr uint8_t kUnitAccMg = 0x01;
constexpr uint8_t kUnitGyrRad = 0x02;
constexpr uint8_t kUnitEulRad = 0x04;
constexpr uint8_t kUnitTempF = 0x10;

constexpr uint8_t kSysStatusIdle = 0;
constexpr uint8_t kSysStatusFusion = 5;
constexpr uint8_t kSysStatusNoFusion = 6;

constexpr double kPi = 3.14159265358979323846;
constexpr double kG_m_s2 = 9.80665;

// Which outputs each operating mode produces (datasheet mode table).
struct ModeOutputs {
  bool acc, mag, gyr, fusion;
};
constexpr ModeOutputs kModeOutputs[kModeMax + 1] = {
    {false, false, false, false},  // CONFIG
    {true, false, false, false},   // ACCONLY
    {false, true, false, false},   // MAGONLY
    {false, false, true, false},   // GYRONLY
    {true, true, false, false},    // ACCMAG
    {true, false, true, false},    // ACCGYRO
    {false, true, true, false},    // MAGGYRO
    {true, true, true, false},     // AMG
    {true, false, true, true},     // IMUPLUS
    {true, true, false, true},     // COMPASS
    {true, true, false, true},     // M4G
    {true, true, true, true},      // NDOF_FMC_OFF
    {true, true, true, true},      // NDOF
};

[[nodiscard]] int16_t saturate_i16(double v) {
  const double r = std::nearbyint(v);
  if (r > 32767.0) return INT16_MAX;
  if (r < -32768.0) return INT16_MIN;
  return static_cast<int16_t>(r);
}

void put_i16(uint8_t* p, int16_t v) {
  const auto u = static_cast<uint16_t>(v);
  p[0] = static_cast<uint8_t>(u & 0xFF);
  p[1] = static_cast<uint8_t>(u >> 8);
}

}  // namespace

Bno055Model::Bno055Model(const Bno055ModelConfig& config) : config_(config), rng_(config.seed) {
  load_defaults();
  down_until_t_us_ = config_.power_on_t_us + config_.boot_time_us;
  mode_ready_t_us_ = down_until_t_us_;
}

void Bno055Model::set_truth(const Bno055Truth& truth) {
  truth_ = truth;
  ++truth_version_;
}

void Bno055Model::power_cycle(uint64_t at_us, uint64_t off_us) {
  events_.push_back({at_us, off_us + config_.boot_time_us});
}

void Bno055Model::reset_at(uint64_t at_us) { events_.push_back({at_us, config_.reset_time_us}); }

void Bno055Model::load_defaults() {
  for (auto& page : regs_) page.fill(0);
  auto& r = regs_[0];
  r[kRegChipId] = 0xA0;
  r[0x01] = 0xFB;  // ACC_ID
  r[0x02] = 0x32;  // MAG_ID
  r[0x03] = 0x0F;  // GYR_ID
  r[0x04] = static_cast<uint8_t>(config_.sw_rev & 0xFF);
  r[0x05] = static_cast<uint8_t>(config_.sw_rev >> 8);
  r[0x06] = config_.bl_rev;
  r[kRegStResult] = 0x0F;  // all self-tests passed
  r[kRegUnitSel] = config_.unit_sel_reset;
  r[kRegOprMode] = kOprReservedBits | kModeConfig;
  r[kRegAxisMapConfig] = 0x24;
  r[kRegAxisMapSign] = 0x00;
  regs_[1][kRegPageId] = 1;
  staged_lsb_.fill(0);
  data_.fill(0);
  data_tick_ = UINT64_MAX;
  pointer_ = 0;
}

void Bno055Model::reset_now(uint64_t at_us, uint64_t down_us) {
  load_defaults();
  down_until_t_us_ = std::max(down_until_t_us_, at_us + down_us);
  mode_ready_t_us_ = down_until_t_us_;
  ++resets_;
}

void Bno055Model::apply_events(uint64_t now_us) {
  std::sort(events_.begin(), events_.end(), [](const Event& a, const Event& b) { return a.at_us < b.at_us; });
  std::size_t done = 0;
  while (done < events_.size() && events_[done].at_us <= now_us) {
    reset_now(events_[done].at_us, events_[done].down_us);
    ++done;
  }
  events_.erase(events_.begin(), events_.begin() + static_cast<std::ptrdiff_t>(done));
}

bool Bno055Model::data_valid(uint64_t now_us) const {
  return mode() != kModeConfig && now_us >= mode_ready_t_us_;
}

bool Bno055Model::config_writable(uint64_t now_us) const {
  return mode() == kModeConfig && now_us >= mode_ready_t_us_;
}

hal::I2cStatus Bno055Model::on_write(const uint8_t* data, std::size_t len, uint64_t now_us) {
  apply_events(now_us);
  if (!awake(now_us)) return hal::I2cStatus::nack_address;
  if (len == 0) return hal::I2cStatus::ok;
  pointer_ = data[0];
  for (std::size_t i = 1; i < len; ++i) {
    // A byte that reset the part is acknowledged; the part is gone for the ones after it.
    if (!awake(now_us)) return hal::I2cStatus::nack_data;
    write_register(pointer_, data[i], now_us);
    ++pointer_;
  }
  return hal::I2cStatus::ok;
}

hal::I2cStatus Bno055Model::on_read(uint8_t* out, std::size_t len, uint64_t now_us) {
  apply_events(now_us);
  if (!awake(now_us)) return hal::I2cStatus::nack_address;
  // One coherent snapshot per burst, as the part's data shadowing gives.
  refresh_data(now_us);
  for (std::size_t i = 0; i < len; ++i) {
    out[i] = read_register(pointer_, now_us);
    ++pointer_;
  }
  return hal::I2cStatus::ok;
}

uint8_t Bno055Model::read_register(uint8_t addr, uint64_t now_us) {
  const uint8_t page = regs_[0][kRegPageId];
  if (addr == kRegPageId) return page;
  if (addr >= 0x80) return 0;
  if (page == 1) return regs_[1][addr];
  if (addr >= kRegDataFirst && addr <= kRegDataLast) return data_[addr - kRegDataFirst];
  if (addr == kRegSysStatus) {
    if (!data_valid(now_us)) return kSysStatusIdle;
    return kModeOutputs[mode()].fusion ? kSysStatusFusion : kSysStatusNoFusion;
  }
  if (addr == kRegSysTrigger) return regs_[0][kRegSysTrigger] & kSysTriggerClkSel;  // other bits self-clear
  return regs_[0][addr];
}

void Bno055Model::write_register(uint8_t addr, uint8_t value, uint64_t now_us) {
  if (addr == kRegPageId) {
    if (value <= 1) regs_[0][kRegPageId] = value;
    return;
  }
  if (addr >= 0x80) return;
  const bool cfg = config_writable(now_us);
  if (regs_[0][kRegPageId] == 1) {
    if (cfg && addr >= kPage1ConfigFirst && addr <= kPage1ConfigLast) regs_[1][addr] = value;
    return;
  }
  auto& r = regs_[0];
  switch (addr) {
    case kRegOprMode: {
      // Datasheet: bits 3..0 are the mode, 7..4 reserved. A write replaces the whole byte, so
      // the power-up 0x10 is gone after the first accepted write: NDOF reads back 0x0C (what
      // Adafruit's getMode() returns on a part), not 0x1C.
      const uint8_t m = value & 0x0F;
      if (m > kModeMax) return;
      const bool same_mode = m == mode();
      r[kRegOprMode] = m;
      if (same_mode) return;  // no mode switch: nothing restarts
      mode_ready_t_us_ = now_us + (m == kModeConfig ? config_.to_config_time_us : config_.from_config_time_us);
      data_tick_ = UINT64_MAX;
      return;
    }
    case kRegSysTrigger:
      if ((value & kSysTriggerRstSys) != 0) {
        reset_now(now_us, config_.reset_time_us);
        return;
      }
      if (cfg) r[kRegSysTrigger] = value & kSysTriggerClkSel;
      return;
    case kRegUnitSel:
      if (cfg) r[addr] = value & kUnitSelDefinedBits;
      return;
    case kRegPwrMode:
      if (cfg && value <= 2) r[addr] = value;
      return;
    case kRegTempSource:
      if (cfg) r[addr] = value & 0x03;
      return;
    case kRegAxisMapConfig:
      if (cfg) r[addr] = value & 0x3F;
      return;
    case kRegAxisMapSign:
      if (cfg) r[addr] = value & 0x07;
      return;
    default:
      break;
  }
  if (!cfg) return;
  if (addr >= kRegSicFirst && addr <= kRegSicLast) {
    r[addr] = value;
  } else if (addr >= kRegOffsetFirst && addr <= kRegOffsetLast) {
    // Pairs start at 0x55 (LSB); the part applies a pair only when its MSB arrives.
    if (((addr - kRegOffsetFirst) & 1) == 0) {
      staged_lsb_[addr] = value;
    } else {
      r[addr - 1] = staged_lsb_[addr - 1];
      r[addr] = value;
    }
  }
  // Anything else is read-only, reserved or undefined: ignored.
}

void Bno055Model::refresh_data(uint64_t now_us) {
  if (!data_valid(now_us)) {
    data_.fill(0);
    data_tick_ = UINT64_MAX;
    return;
  }
  const uint64_t period = std::max<uint64_t>(config_.output_period_us, 1);
  const uint64_t tick = (now_us - mode_ready_t_us_) / period;
  if (tick == data_tick_ && truth_version_ == data_version_) return;
  data_tick_ = tick;
  data_version_ = truth_version_;

  const ModeOutputs out = kModeOutputs[mode()];
  const uint8_t units = regs_[0][kRegUnitSel];
  const Bno055Noise& n = config_.noise;
  auto noisy = [this](double v, double sd) {
    if (sd <= 0.0) return v;
    std::normal_distribution<double> dist(0.0, sd);
    return v + dist(rng_);
  };
  auto put = [this](uint8_t reg, int16_t v) { put_i16(&data_[reg - kRegDataFirst], v); };

  data_.fill(0);
  for (int i = 0; i < 3; ++i) {
    const auto k = static_cast<uint8_t>(2 * i);
    const std::size_t ax = static_cast<std::size_t>(i);
    if (out.acc) put(static_cast<uint8_t>(0x08 + k), raw_accel(noisy(truth_.accel_m_s2[ax], n.accel_m_s2), units));
    if (out.mag) put(static_cast<uint8_t>(0x0E + k), saturate_i16(noisy(truth_.mag_ut[ax], n.mag_ut) * 16.0));
    if (out.gyr) put(static_cast<uint8_t>(0x14 + k), raw_gyro(noisy(truth_.gyro_rad_s[ax], n.gyro_rad_s), units));
    if (out.fusion) {
      put(static_cast<uint8_t>(0x28 + k), raw_accel(noisy(truth_.lin_accel_m_s2[ax], n.accel_m_s2), units));
      const double grv = truth_.accel_m_s2[ax] - truth_.lin_accel_m_s2[ax];
      put(static_cast<uint8_t>(0x2E + k), raw_accel(noisy(grv, n.accel_m_s2), units));
    }
  }
  if (out.fusion) {
    std::array<double, 4> q{};
    double norm2 = 0.0;
    for (std::size_t i = 0; i < 4; ++i) {
      q[i] = noisy(truth_.quat_wxyz[i], n.quat);
      norm2 += q[i] * q[i];
    }
    const double norm = std::sqrt(norm2);
    if (norm > 0.0) {
      for (auto& c : q) c /= norm;
    } else {
      q = {1.0, 0.0, 0.0, 0.0};
    }
    for (std::size_t i = 0; i < 4; ++i) put(static_cast<uint8_t>(0x20 + 2 * i), raw_quat(q[i]));

    std::array<double, 3> eul{};
    if (truth_.euler_deg) {
      eul = *truth_.euler_deg;
    } else {
      const double w = q[0], x = q[1], y = q[2], z = q[3];
      double heading = std::atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)) * 180.0 / kPi;
      if (heading < 0.0) heading += 360.0;
      const double roll = std::atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)) * 180.0 / kPi;
      const double pitch = std::asin(std::clamp(2.0 * (w * y - z * x), -1.0, 1.0)) * 180.0 / kPi;
      eul = {heading, roll, pitch};
    }
    for (std::size_t i = 0; i < 3; ++i) put(static_cast<uint8_t>(0x1A + 2 * i), raw_euler(eul[i], units));
  }
  data_[0x34 - kRegDataFirst] = raw_temp(truth_.temp_c, units);
  data_[0x35 - kRegDataFirst] = calib_stat(truth_.calib_sys, truth_.calib_gyr, truth_.calib_acc, truth_.calib_mag);
}

int16_t Bno055Model::raw_accel(double m_s2, uint8_t unit_sel) {
  return saturate_i16((unit_sel & kUnitAccMg) != 0 ? m_s2 / kG_m_s2 * 1000.0 : m_s2 * 100.0);
}

int16_t Bno055Model::raw_gyro(double rad_s, uint8_t unit_sel) {
  return saturate_i16((unit_sel & kUnitGyrRad) != 0 ? rad_s * 900.0 : rad_s * 180.0 / kPi * 16.0);
}

int16_t Bno055Model::raw_euler(double deg, uint8_t unit_sel) {
  return saturate_i16((unit_sel & kUnitEulRad) != 0 ? deg * kPi / 180.0 * 900.0 : deg * 16.0);
}

int16_t Bno055Model::raw_quat(double q) { return saturate_i16(q * 16384.0); }

uint8_t Bno055Model::raw_temp(double temp_c, uint8_t unit_sel) {
  const double raw = (unit_sel & kUnitTempF) != 0 ? (temp_c * 9.0 / 5.0 + 32.0) * 2.0 : temp_c;
  const double r = std::clamp(std::nearbyint(raw), -128.0, 127.0);
  return static_cast<uint8_t>(static_cast<int8_t>(r));
}

uint8_t Bno055Model::calib_stat(uint8_t sys, uint8_t gyr, uint8_t acc, uint8_t mag) {
  auto c = [](uint8_t v) { return static_cast<uint8_t>(std::min<uint8_t>(v, 3)); };
  return static_cast<uint8_t>(c(sys) << 6 | c(gyr) << 4 | c(acc) << 2 | c(mag));
}

}  // namespace icgt::sim
