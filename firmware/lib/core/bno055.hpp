// Driver for the Bosch BNO055 absolute-orientation IMU on I2C.
//
// A stepped state machine: the main loop calls step(now_us) as often as it likes; each call
// does at most one short group of I2C transfers (one register access during init, two data
// bursts when a sample is due) and returns at once. Every wait the part needs (boot, reset,
// mode switches) is a "not before" time kept by the driver, never a delay, and every wait
// for the part has a deadline. A missing or misbehaving part costs a few NACKed address
// bytes per back-off period and nothing else.
//
// Init sequence (the order the part needs, per the vendor library; sensors.md §1.2):
//   probe (address-only write, every 10 ms until the boot deadline) -> CHIP_ID == 0xA0 ->
//   OPR_MODE <- CONFIG (30 ms) -> SYS_TRIGGER <- RST_SYS (poll CHIP_ID every 10 ms until
//   0xA0, with a deadline; then 50 ms) -> PWR_MODE <- normal (10 ms) -> PAGE_ID <- 0 ->
//   SYS_TRIGGER <- 0x00 / 0x80 external crystal (10 ms) -> read UNIT_SEL ->
//   OPR_MODE <- fusion mode (30 ms) -> read back OPR_MODE -> running.
//
// Failures: any transfer that does not succeed (except the NACKs expected while the part
// boots), a chip id that stays wrong, a mode that does not read back, or a part that reset
// itself while running (it returns in CONFIG mode, where the quaternion reads all zero;
// confirmed by reading OPR_MODE). Each failure sends the driver back to init after an
// exponential back-off (100 ms doubling to 5 s; reset to 100 ms once running again).
#pragma once

#include <cstdint>

#include "hal/hal.hpp"

namespace icgt::core {

struct Bno055Config {
  uint8_t addr7 = 0x28;     // 0x28 (COM3 low) or 0x29 (COM3 high)
  uint8_t opr_mode = 0x0C;  // a fusion mode, 0x08 IMUPLUS .. 0x0C NDOF: samples carry the quaternion
  bool ext_crystal = false;  // SYS_TRIGGER CLK_SEL: clock the part from the board's 32.768 kHz crystal
  uint16_t rate_hz = 100;    // sample rate, 1..100 (the part's fusion output rate is 100 Hz)
};

// One reading of the data registers. Axes are the part's (AXIS_MAP left at its default).
struct ImuSample {
  uint64_t read_start_t_us = 0;  // device clock just before the first data burst
  uint64_t read_end_t_us = 0;    // device clock just after the last data burst
  float quat_w = 1.0F;           // unit quaternion (fusion output)
  float quat_x = 0.0F;
  float quat_y = 0.0F;
  float quat_z = 0.0F;
  float gyro_x_rad_s = 0.0F;
  float gyro_y_rad_s = 0.0F;
  float gyro_z_rad_s = 0.0F;
  float accel_x_m_s2 = 0.0F;  // including gravity
  float accel_y_m_s2 = 0.0F;
  float accel_z_m_s2 = 0.0F;
  float lin_accel_x_m_s2 = 0.0F;  // gravity removed by the fusion
  float lin_accel_y_m_s2 = 0.0F;
  float lin_accel_z_m_s2 = 0.0F;
  int8_t temp_c = 0;
  uint8_t calib_stat = 0;      // raw CALIB_STAT: bits 7:6 SYS, 5:4 GYR, 3:2 ACC, 1:0 MAG (3 = calibrated)
  bool reinitialised = false;  // first sample after an init (the first init included)
};

// What one step() call did.
enum class Bno055Step : uint8_t {
  idle,          // nothing due yet; no bus traffic
  busy,          // init or check traffic; no new sample
  sample_ready,  // sample() holds a new reading
  error,         // a failure was detected; the driver is backing off before re-init
};

enum class Bno055State : uint8_t {
  absent,        // the last probe phase ended without the address being acknowledged
  initialising,  // init sequence in progress (or probing again after a back-off)
  running,       // producing samples
  backing_off,   // a present part failed; waiting before the next init
};

class Bno055 {
 public:
  // An invalid config (see valid()) is replaced field by field with the nearest valid value
  // (rate clamped to 1..100 Hz; a bad address or mode falls back to the default).
  Bno055(hal::I2cBus& bus, const hal::Clock& clock, const Bno055Config& config = {});

  [[nodiscard]] static bool valid(const Bno055Config& config);

  // Advances the state machine; never waits. Call at least every few ms while running.
  [[nodiscard]] Bno055Step step(uint64_t now_us);

  // The latest sample; valid after step() returned sample_ready, kept until the next one.
  [[nodiscard]] const ImuSample& sample() const { return sample_; }

  [[nodiscard]] Bno055State state() const { return state_; }
  // True from a probe the part acknowledged until a probe phase ends unanswered.
  [[nodiscard]] bool present() const { return present_; }
  [[nodiscard]] bool running() const { return state_ == Bno055State::running; }
  // Failed transfers, not counting address NACKs while the part is expected to be booting.
  [[nodiscard]] uint32_t i2c_errors() const { return i2c_errors_; }
  // Init sequences restarted because a present part failed (saturates). Retries of a part
  // that never answered and inits caused by reconfigure() are not counted.
  [[nodiscard]] uint16_t reinits() const { return reinits_; }
  // Earliest now_us at which step() will touch the bus (for a loop that wants to sleep).
  [[nodiscard]] uint64_t next_step_t_us() const { return not_before_t_us_; }

  [[nodiscard]] const Bno055Config& config() const { return config_; }
  // Returns false and changes nothing if the config is invalid. A new rate takes effect at
  // once; a new address, mode or crystal setting restarts the init sequence.
  [[nodiscard]] bool reconfigure(const Bno055Config& config);

 private:
  enum class Phase : uint8_t {
    start,
    probe,
    check_id,
    enter_config,
    reset,
    wait_reset,
    power_mode,
    page,
    clock_select,
    read_units,
    set_mode,
    verify_mode,
    read_data,
    confirm_reset,
    back_off,
  };

  [[nodiscard]] Bno055Step step_phase(uint64_t now_us);
  [[nodiscard]] Bno055Step read_data(uint64_t now_us);
  // Counts the failed transfer and backs off; returns Bno055Step::error.
  [[nodiscard]] Bno055Step fail_transfer(uint64_t now_us);
  [[nodiscard]] Bno055Step fail(uint64_t now_us);
  // Writes one register and schedules the next phase after wait_us.
  [[nodiscard]] Bno055Step write_then(uint8_t reg, uint8_t value, Phase next, uint64_t wait_us, uint64_t now_us);
  void decode(const uint8_t* acc_mag_gyr, const uint8_t* qua_lia_grv);

  [[nodiscard]] hal::I2cDevice dev() const { return hal::I2cDevice(bus_, config_.addr7); }

  hal::I2cBus& bus_;
  const hal::Clock& clock_;
  Bno055Config config_;
  Phase phase_ = Phase::start;
  Bno055State state_ = Bno055State::initialising;
  bool present_ = false;
  bool failed_present_ = false;  // the last failure was of a part that had answered
  bool first_sample_ = true;
  bool gyro_rad_s_unit_ = false;  // UNIT_SEL as read during init
  bool accel_mg_unit_ = false;
  bool temp_f_unit_ = false;
  uint64_t not_before_t_us_ = 0;
  uint64_t deadline_t_us_ = 0;
  uint64_t period_us_ = 10'000;
  uint64_t backoff_us_;
  uint32_t i2c_errors_ = 0;
  uint16_t reinits_ = 0;
  ImuSample sample_;
};

}  // namespace icgt::core
