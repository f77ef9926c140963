// Register-level model of a Garmin LIDAR-Lite v3 / v3HP (7-bit address 0x62), strict in
// the ways shared/reference/sensors.md §2 says silicon is.
//
// Bus behaviour (a "burst" here is the bytes after the address byte, as SimI2cBus delivers
// them; Garmin's guideline counts the address byte too, so its "3-byte write" is our
// 2-byte burst):
//  - Post-2018 FPGA I2C block: the first byte of every write burst sets the register
//    pointer; a 1-byte burst sets only the pointer and writes nothing. The pre-2018
//    "pointer write, then separate data write" is not modelled.
//  - v3: pointer bit7 = auto-increment (0x8F reads 0x0F, 0x10, ...); without it a
//    multi-byte read repeats the same register. v3HP auto-increments always and treats
//    the pointer as a full 8-bit address (the vendor never sets bit7 there), so 0x8F is
//    an undefined register on v3HP. That strictness is a choice, not verified on silicon.
//  - Reads work after either a STOP or a repeated start (both are recorded).
//  - Undefined registers read 0x00; writes to them, to read-only registers and unknown
//    commands are ignored (and counted).
//  - Power-up (at power_on_t_us) and 0x00 <- 0x00 (reset): defaults reloaded, then every
//    transfer NACKs for reset_us (~22 ms, sensors.md §2.1).
//  - Acquisition: v3 0x00 <- 0x04 (with receiver bias correction) or 0x03 (without);
//    v3HP 0x00 <- 0x01. Only the commands the vendor library sends for the variant start a
//    measurement (strict; what silicon does with the others is not documented). STATUS
//    bit0 is set for the conversion time, then the result latches into 0x0F (high) /
//    0x10 (low) and 0x0E; until then those registers keep the PREVIOUS result. A command
//    while busy restarts the conversion.
//  - Conversion time = conversion_us at SIG_COUNT_VAL 0x80, scaled as
//    1/4 + 3/4 * count / 0x80 (so 0xFF, the max-range preset, takes ~1.75x), plus
//    bias_extra_us for a v3 bias-corrected acquisition. The defaults are Garmin's
//    operation manuals: v3 "update rate 270 Hz typical, 650 Hz fast mode" (70 % target):
//    3.7 ms at the default count 0x80, and the scaling gives 1.55 ms (645 Hz) at preset 1's
//    0x1D, so both datasheet figures come out; v3HP "greater than 1 kHz": 0.95 ms at 0x80.
//    Quick termination (ACQ_CONFIG bit 3 clear) and signal-strength dependence are not
//    modelled: every acquisition takes its full time.
//  - No signal (set_no_signal): the result latches with STATUS bit3 set, distance 1 cm
//    (the value v3 units are reported to give without a return) and signal strength 0.
//    The distance and signal strength are from the truth at the acquisition command.
//  - STATUS: bit0 busy, bit3 no signal; v3 also sets bit5 (health, per the v3 manual's
//    register map) so a driver that compares the whole byte with 0 fails here as on a part.
//  - I2C address changes (0x18..0x1E) are stored but do not move the part: the bus
//    attaches models by address.
#pragma once

#include <cstddef>
#include <cstdint>
#include <random>

#include "board/sim_i2c_bus.hpp"

namespace icgt::sim {

enum class LidarLiteVariant : uint8_t { v3, v3hp };

struct LidarLiteModelConfig {
  LidarLiteVariant variant = LidarLiteVariant::v3;
  uint16_t unit_id = 0x4C31;      // 0x16 (high) / 0x17 (low); a real part's is non-zero
  uint32_t conversion_us = 0;      // at SIG_COUNT_VAL 0x80; 0 = the variant's datasheet figure
  uint64_t power_on_t_us = 0;      // supply applied; NACKs for reset_us from here
  uint32_t bias_extra_us = 200;    // v3 0x04 only
  uint32_t reset_us = 22'000;      // NACK window after a reset or power-up
  double noise_sigma_cm = 0.0;
  uint64_t seed = 1;
  uint8_t signal_strength = 100;   // 0x0E when there is a return
};

class LidarLiteModel final : public I2cDeviceModel {
 public:
  static constexpr uint8_t kDefaultAddr7 = 0x62;
  static constexpr uint32_t kV3ConversionUs = 3'700;    // 270 Hz typical (v3 manual)
  static constexpr uint32_t kV3hpConversionUs = 950;    // > 1 kHz (v3HP manual)

  explicit LidarLiteModel(const LidarLiteModelConfig& config = {});

  [[nodiscard]] hal::I2cStatus on_write(const uint8_t* data, std::size_t len, uint64_t now_us) override;
  [[nodiscard]] hal::I2cStatus on_read(uint8_t* out, std::size_t len, uint64_t now_us) override;
  void on_join(hal::I2cJoin join) override;

  // Truth, sampled when an acquisition command arrives.
  void set_range_cm(double range_cm) { range_cm_ = range_cm; }
  void set_no_signal(bool no_signal) { no_signal_ = no_signal; }
  void set_noise_sigma_cm(double sigma_cm) { cfg_.noise_sigma_cm = sigma_cm; }

  // Faults. Power is lost at t_us for off_us, then the part boots with defaults and NACKs
  // for reset_us more. Stuck busy holds STATUS bit0 set, and acquisitions started while it
  // is set never latch; a reset does not clear it (it models a broken part), clearing it
  // drops the hung acquisition. A conversion already running when it is set still
  // completes in the background: setters have no time, so they never rewrite the past.
  void power_cycle_at(uint64_t t_us, uint32_t off_us);
  void set_stuck_busy(bool stuck);

  // Inspection, without bus side effects. reg() is the stored value (STATUS is computed on
  // read and not stored).
  [[nodiscard]] uint8_t reg(uint8_t addr) const { return regs_[addr]; }
  [[nodiscard]] const LidarLiteModelConfig& config() const { return cfg_; }
  [[nodiscard]] uint32_t conversion_time_us(bool bias_corrected) const;
  [[nodiscard]] uint32_t acquisitions() const { return acquisitions_; }
  [[nodiscard]] uint32_t bias_corrected_acquisitions() const { return bias_acquisitions_; }  // v3 0x04
  [[nodiscard]] uint32_t uncorrected_acquisitions() const { return plain_acquisitions_; }     // v3 0x03
  [[nodiscard]] uint32_t commands_while_busy() const { return commands_while_busy_; }
  [[nodiscard]] uint32_t resets() const { return resets_; }
  [[nodiscard]] uint32_t nacks() const { return nacks_; }
  [[nodiscard]] uint32_t pointer_only_writes() const { return pointer_only_writes_; }
  [[nodiscard]] uint32_t ignored_writes() const { return ignored_writes_; }
  [[nodiscard]] uint32_t stop_joins() const { return stop_joins_; }
  [[nodiscard]] uint32_t repeated_start_joins() const { return repeated_start_joins_; }

 private:
  enum Access : uint8_t { undefined = 0, ro, rw, command };

  void load_defaults();
  void update(uint64_t now_us);
  void write_register(uint8_t addr, uint8_t value, uint64_t now_us);
  [[nodiscard]] uint8_t read_register(uint8_t addr) const;
  void start_acquisition(bool bias_corrected, uint64_t now_us);
  [[nodiscard]] uint8_t register_of(uint8_t pointer) const;
  [[nodiscard]] bool auto_increments(uint8_t pointer) const;
  [[nodiscard]] uint8_t next_register(uint8_t addr) const;
  [[nodiscard]] bool unavailable(uint64_t now_us);

  LidarLiteModelConfig cfg_;
  std::mt19937_64 rng_;
  Access access_[256] = {};
  uint8_t regs_[256] = {};
  uint8_t pointer_ = 0;

  double range_cm_ = 500.0;
  bool no_signal_ = false;
  bool stuck_busy_ = false;

  bool converting_ = false;
  uint64_t busy_until_us_ = 0;
  uint16_t pending_distance_cm_ = 0;
  uint8_t pending_strength_ = 0;
  bool pending_no_signal_ = false;
  bool last_no_signal_ = false;

  uint64_t unavailable_until_us_ = 0;
  bool power_cycle_pending_ = false;
  uint64_t power_off_us_ = 0;
  uint64_t power_on_us_ = 0;

  uint32_t acquisitions_ = 0;
  uint32_t bias_acquisitions_ = 0;
  uint32_t plain_acquisitions_ = 0;
  uint32_t commands_while_busy_ = 0;
  uint32_t resets_ = 0;
  uint32_t nacks_ = 0;
  uint32_t pointer_only_writes_ = 0;
  uint32_t ignored_writes_ = 0;
  uint32_t stop_joins_ = 0;
  uint32_t repeated_start_joins_ = 0;
};

}  // namespace icgt::sim
