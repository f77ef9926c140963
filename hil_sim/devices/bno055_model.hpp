// Register-level model of the Bosch BNO055 on I2C (contract: shared reference sensors.md §1).
//
// Strict like silicon: NACKs its address while booting or resetting, holds the data
// registers at zero in CONFIG mode and during a mode switch, ignores writes to read-only
// registers, latches an offset pair only on its MSB write, reads 0 from undefined registers.
// Data come from a settable truth (orientation, rates, accelerations, calibration,
// temperature) plus optional seeded Gaussian noise, and change at the 100 Hz output rate.
//
// Modelling choices beyond sensors.md (datasheet, not verified against silicon here):
//  - configuration registers (UNIT_SEL, PWR_MODE, TEMP_SOURCE, AXIS_MAP, SIC, offsets, CLK_SEL)
//    only take writes in CONFIG mode once the switch into it has completed; RST_SYS and
//    PAGE_ID are honoured in any mode;
//  - AXIS_MAP and PWR_MODE are stored and read back but do not alter the data;
//  - UNIT_SEL bit 7 (orientation convention) is stored but does not alter the Euler angles;
//  - OPR_MODE reads 0x10 after power-up and reset (reserved bit 4, observed on a bench unit,
//    sensors.md §1); bits 7..4 are reserved (datasheet) and a write replaces the byte, so after
//    the first accepted write it reads the mode alone (NDOF: 0x0C). Modes above 0x0C are ignored.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <random>
#include <vector>

#include "board/sim_i2c_bus.hpp"

namespace icgt::sim {

// Standard deviations of the Gaussian noise added to each output (0 = exact).
struct Bno055Noise {
  double quat = 0.0;  // per component, before renormalisation
  double gyro_rad_s = 0.0;
  double accel_m_s2 = 0.0;  // ACC, LIA and GRV independently
  double mag_ut = 0.0;
};

struct Bno055ModelConfig {
  uint64_t power_on_t_us = 0;        // supply applied at this time
  uint64_t boot_time_us = 650'000;   // power-on to first address ACK
  uint64_t reset_time_us = 650'000;  // RST_SYS (or injected reset) to first address ACK
  uint64_t to_config_time_us = 19'000;
  uint64_t from_config_time_us = 7'000;
  uint64_t output_period_us = 10'000;  // 100 Hz data rate
  uint16_t sw_rev = 0x0311;
  uint8_t bl_rev = 0x15;
  uint8_t unit_sel_reset = 0x80;  // sensors.md: reset value believed 0x80 (bit 7 only)
  Bno055Noise noise;
  uint64_t seed = 0x1C6755;
};

// The physical state the part senses, in its own (default P1) axes.
struct Bno055Truth {
  std::array<double, 4> quat_wxyz{1.0, 0.0, 0.0, 0.0};
  std::array<double, 3> gyro_rad_s{};
  std::array<double, 3> accel_m_s2{0.0, 0.0, 9.80665};  // including gravity; GRV = accel - lin_accel
  std::array<double, 3> lin_accel_m_s2{};
  std::array<double, 3> mag_ut{20.0, 0.0, -40.0};
  // Heading, roll, pitch [deg]; derived from quat_wxyz (ZYX, heading in [0, 360)) when empty.
  std::optional<std::array<double, 3>> euler_deg;
  double temp_c = 25.0;
  uint8_t calib_sys = 3;  // 0..3 each
  uint8_t calib_gyr = 3;
  uint8_t calib_acc = 3;
  uint8_t calib_mag = 3;
};

class Bno055Model final : public I2cDeviceModel {
 public:
  explicit Bno055Model(const Bno055ModelConfig& config = {});

  void set_truth(const Bno055Truth& truth);
  [[nodiscard]] const Bno055Truth& truth() const { return truth_; }

  // Fault injection. Supply lost at at_us for off_us, then a power-on boot.
  void power_cycle(uint64_t at_us, uint64_t off_us = 0);
  // A spontaneous reset (brown-out, watchdog) at at_us: as RST_SYS, back in CONFIG with defaults.
  void reset_at(uint64_t at_us);

  // Inspection for tests (no side effects; data registers are computed only on bus reads).
  [[nodiscard]] uint8_t reg(uint8_t page, uint8_t addr) const { return regs_[page & 1][addr & 0x7F]; }
  [[nodiscard]] bool ext_crystal() const { return (regs_[0][0x3F] & 0x80) != 0; }
  [[nodiscard]] uint8_t mode() const { return regs_[0][0x3D] & 0x0F; }
  [[nodiscard]] bool awake(uint64_t now_us) const { return now_us >= down_until_t_us_; }
  [[nodiscard]] uint32_t resets() const { return resets_; }
  [[nodiscard]] std::optional<hal::I2cJoin> last_join() const { return last_join_; }

  [[nodiscard]] hal::I2cStatus on_write(const uint8_t* data, std::size_t len, uint64_t now_us) override;
  [[nodiscard]] hal::I2cStatus on_read(uint8_t* out, std::size_t len, uint64_t now_us) override;
  void on_join(hal::I2cJoin join) override { last_join_ = join; }

  // The raw counts a value produces under a UNIT_SEL setting (saturated to int16).
  [[nodiscard]] static int16_t raw_accel(double m_s2, uint8_t unit_sel);
  [[nodiscard]] static int16_t raw_gyro(double rad_s, uint8_t unit_sel);
  [[nodiscard]] static int16_t raw_euler(double deg, uint8_t unit_sel);
  [[nodiscard]] static int16_t raw_quat(double q);
  [[nodiscard]] static uint8_t raw_temp(double temp_c, uint8_t unit_sel);
  [[nodiscard]] static uint8_t calib_stat(uint8_t sys, uint8_t gyr, uint8_t acc, uint8_t mag);

 private:
  struct Event {
    uint64_t at_us;
    uint64_t down_us;  // unreachable for this long from at_us
  };

  void apply_events(uint64_t now_us);
  void load_defaults();
  void reset_now(uint64_t at_us, uint64_t down_us);
  void write_register(uint8_t addr, uint8_t value, uint64_t now_us);
  [[nodiscard]] uint8_t read_register(uint8_t addr, uint64_t now_us);
  [[nodiscard]] bool data_valid(uint64_t now_us) const;
  [[nodiscard]] bool config_writable(uint64_t now_us) const;
  void refresh_data(uint64_t now_us);

  Bno055ModelConfig config_;
  Bno055Truth truth_;
  uint64_t truth_version_ = 0;
  std::mt19937_64 rng_;
  std::array<std::array<uint8_t, 128>, 2> regs_{};
  std::array<uint8_t, 128> staged_lsb_{};  // offset LSBs waiting for their MSB write
  std::array<uint8_t, 0x36 - 0x08> data_{};  // 0x08..0x35 as last computed
  uint64_t data_tick_ = UINT64_MAX;
  uint64_t data_version_ = UINT64_MAX;
  uint8_t pointer_ = 0;
  uint64_t down_until_t_us_ = 0;
  uint64_t mode_ready_t_us_ = 0;  // the current mode switch completes here
  uint32_t resets_ = 0;
  std::vector<Event> events_;
  std::optional<hal::I2cJoin> last_join_;
};

}  // namespace icgt::sim
