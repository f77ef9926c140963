#include "devices/lidar_lite_model.hpp"

#include <algorithm>
#include <cmath>

namespace icgt::sim {
namespace {

constexpr uint8_t kRegAcqCommand = 0x00;
constexpr uint8_t kRegStatus = 0x01;
constexpr uint8_t kRegSigCount = 0x02;
constexpr uint8_t kRegAcqConfig = 0x04;
constexpr uint8_t kRegSignalStrength = 0x0E;
constexpr uint8_t kRegDistanceHigh = 0x0F;
constexpr uint8_t kRegDistanceLow = 0x10;
constexpr uint8_t kRegRefCount = 0x12;
constexpr uint8_t kRegUnitIdHigh = 0x16;
constexpr uint8_t kRegUnitIdLow = 0x17;

constexpr uint8_t kStatusBusy = 0x01;
constexpr uint8_t kStatusNoSignal = 0x08;
constexpr uint8_t kStatusHealth = 0x20;
constexpr uint64_t kNever = UINT64_MAX;

}  // namespace

LidarLiteModel::LidarLiteModel(const LidarLiteModelConfig& config) : cfg_(config), rng_(config.seed) {
  const bool v3 = cfg_.variant == LidarLiteVariant::v3;
  if (cfg_.conversion_us == 0) cfg_.conversion_us = v3 ? kV3ConversionUs : kV3hpConversionUs;
  unavailable_until_us_ = cfg_.power_on_t_us + cfg_.reset_us;  // booting after power-up
  access_[kRegAcqCommand] = command;
  for (uint8_t r : {kRegStatus, kRegSignalStrength, kRegDistanceHigh, kRegDistanceLow, kRegUnitIdHigh, kRegUnitIdLow,
                    uint8_t{0x0C}, uint8_t{0x0D}}) {
    access_[r] = ro;  // 0x0C peak correlation, 0x0D noise peak
  }
  for (uint8_t r : {kRegSigCount, kRegAcqConfig, kRegRefCount, uint8_t{0x18}, uint8_t{0x19}, uint8_t{0x1A},
                    uint8_t{0x1C}, uint8_t{0x1E}, uint8_t{0x40}, uint8_t{0x65}}) {
    access_[r] = rw;  // 0x18/0x19 I2C_ID, 0x1A I2C_SEC_ADDR, 0x1C THRESHOLD_BYPASS, 0x1E I2C_CONFIG,
                      // 0x40 test COMMAND, 0x65 POWER_CONTROL
  }
  if (v3) {
    for (uint8_t r : {uint8_t{0x09}, uint8_t{0x14}, uint8_t{0x15}}) access_[r] = ro;  // velocity, last delay
    access_[0x11] = rw;                                                               // outer loop count
    access_[0x5D] = rw;                                                               // acquisition settings
  }
  load_defaults();
}

void LidarLiteModel::load_defaults() {
  std::fill(std::begin(regs_), std::end(regs_), uint8_t{0});
  regs_[kRegSigCount] = 0x80;
  regs_[kRegAcqConfig] = 0x08;
  regs_[kRegRefCount] = 0x05;
  if (cfg_.variant == LidarLiteVariant::v3) regs_[0x11] = 0x01;
  regs_[kRegUnitIdHigh] = static_cast<uint8_t>(cfg_.unit_id >> 8);
  regs_[kRegUnitIdLow] = static_cast<uint8_t>(cfg_.unit_id & 0xFF);
  pointer_ = 0;
  converting_ = false;
  last_no_signal_ = false;
}

void LidarLiteModel::power_cycle_at(uint64_t t_us, uint32_t off_us) {
  power_cycle_pending_ = true;
  power_off_us_ = t_us;
  power_on_us_ = t_us + off_us;
}

uint32_t LidarLiteModel::conversion_time_us(bool bias_corrected) const {
  // A fixed overhead plus integration proportional to the maximum acquisition count.
  const uint64_t base = cfg_.conversion_us;
  const uint64_t t = base / 4 + (base * 3 / 4) * regs_[kRegSigCount] / 0x80;
  return static_cast<uint32_t>(t + (bias_corrected ? cfg_.bias_extra_us : 0));
}

void LidarLiteModel::update(uint64_t now_us) {
  if (power_cycle_pending_ && now_us >= power_off_us_) {
    // Nobody can talk to the part between power loss and the end of its boot, so reloading
    // the defaults at power loss is indistinguishable from doing it at power-up.
    power_cycle_pending_ = false;
    load_defaults();
    unavailable_until_us_ = std::max(unavailable_until_us_, power_on_us_ + cfg_.reset_us);
  }
  if (converting_ && now_us >= busy_until_us_) {
    converting_ = false;
    regs_[kRegDistanceHigh] = static_cast<uint8_t>(pending_distance_cm_ >> 8);
    regs_[kRegDistanceLow] = static_cast<uint8_t>(pending_distance_cm_ & 0xFF);
    regs_[kRegSignalStrength] = pending_strength_;
    last_no_signal_ = pending_no_signal_;
  }
}

bool LidarLiteModel::unavailable(uint64_t now_us) {
  update(now_us);
  if (now_us < unavailable_until_us_) {
    ++nacks_;
    return true;
  }
  return false;
}

uint8_t LidarLiteModel::register_of(uint8_t pointer) const {
  return cfg_.variant == LidarLiteVariant::v3 ? static_cast<uint8_t>(pointer & 0x7F) : pointer;
}

bool LidarLiteModel::auto_increments(uint8_t pointer) const {
  return cfg_.variant == LidarLiteVariant::v3hp || (pointer & 0x80) != 0;
}

uint8_t LidarLiteModel::next_register(uint8_t addr) const {
  const uint8_t next = static_cast<uint8_t>(addr + 1);
  return cfg_.variant == LidarLiteVariant::v3 ? static_cast<uint8_t>(next & 0x7F) : next;
}

hal::I2cStatus LidarLiteModel::on_write(const uint8_t* data, std::size_t len, uint64_t now_us) {
  if (unavailable(now_us)) return hal::I2cStatus::nack_address;
  if (len == 0) return hal::I2cStatus::ok;
  pointer_ = data[0];
  if (len == 1) {
    ++pointer_only_writes_;
    return hal::I2cStatus::ok;
  }
  const bool inc = auto_increments(pointer_);
  uint8_t addr = register_of(pointer_);
  for (std::size_t i = 1; i < len; ++i) {
    write_register(addr, data[i], now_us);
    // A reset reloads the FPGA: the rest of the burst goes nowhere.
    if (now_us < unavailable_until_us_) break;
    if (inc) addr = next_register(addr);
  }
  return hal::I2cStatus::ok;
}

hal::I2cStatus LidarLiteModel::on_read(uint8_t* out, std::size_t len, uint64_t now_us) {
  if (unavailable(now_us)) return hal::I2cStatus::nack_address;
  const bool inc = auto_increments(pointer_);
  uint8_t addr = register_of(pointer_);
  for (std::size_t i = 0; i < len; ++i) {
    out[i] = read_register(addr);
    if (inc) addr = next_register(addr);
  }
  if (inc) {
    pointer_ = cfg_.variant == LidarLiteVariant::v3 ? static_cast<uint8_t>(addr | 0x80) : addr;
  }
  return hal::I2cStatus::ok;
}

void LidarLiteModel::on_join(hal::I2cJoin join) {
  if (join == hal::I2cJoin::stop) {
    ++stop_joins_;
  } else {
    ++repeated_start_joins_;
  }
}

uint8_t LidarLiteModel::read_register(uint8_t addr) const {
  switch (access_[addr]) {
    case undefined:
    case command:
      return 0;
    case ro:
    case rw:
      break;
  }
  if (addr == kRegStatus) {
    uint8_t s = 0;
    if (converting_ || stuck_busy_) s |= kStatusBusy;
    if (last_no_signal_) s |= kStatusNoSignal;
    if (cfg_.variant == LidarLiteVariant::v3) s |= kStatusHealth;
    return s;
  }
  return regs_[addr];
}

void LidarLiteModel::write_register(uint8_t addr, uint8_t value, uint64_t now_us) {
  switch (access_[addr]) {
    case rw:
      regs_[addr] = value;
      return;
    case undefined:
    case ro:
      ++ignored_writes_;
      return;
    case command:
      break;
  }
  const bool v3 = cfg_.variant == LidarLiteVariant::v3;
  if (value == 0x00) {
    ++resets_;
    load_defaults();
    unavailable_until_us_ = now_us + cfg_.reset_us;
  } else if (v3 && (value == 0x03 || value == 0x04)) {
    start_acquisition(value == 0x04, now_us);
  } else if (!v3 && value == 0x01) {
    start_acquisition(false, now_us);
  } else {
    ++ignored_writes_;
  }
}

void LidarLiteModel::start_acquisition(bool bias_corrected, uint64_t now_us) {
  if (converting_) ++commands_while_busy_;
  ++acquisitions_;
  if (cfg_.variant == LidarLiteVariant::v3) {
    if (bias_corrected) {
      ++bias_acquisitions_;
    } else {
      ++plain_acquisitions_;
    }
  }
  pending_no_signal_ = no_signal_;
  if (no_signal_) {
    pending_distance_cm_ = 1;
    pending_strength_ = 0;
  } else {
    double d = range_cm_;
    if (cfg_.noise_sigma_cm > 0.0) d += std::normal_distribution<double>(0.0, cfg_.noise_sigma_cm)(rng_);
    pending_distance_cm_ = static_cast<uint16_t>(std::clamp(std::lround(d), 0L, 0xFFFFL));
    pending_strength_ = cfg_.signal_strength;
  }
  converting_ = true;
  busy_until_us_ = stuck_busy_ ? kNever : now_us + conversion_time_us(bias_corrected);
}

void LidarLiteModel::set_stuck_busy(bool stuck) {
  stuck_busy_ = stuck;
  if (!stuck && converting_ && busy_until_us_ == kNever) converting_ = false;
}

}  // namespace icgt::sim
