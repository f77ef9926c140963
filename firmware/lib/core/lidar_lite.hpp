// Garmin LIDAR-Lite v3 / v3HP range finder: a non-blocking, stepped driver.
//
// The ranging traffic is Garmin's Arduino library's (shared/reference/sensors.md §2): the
// same preset writes, acquisition commands, busy register, distance pointer and bus
// framing. What differs is that nothing waits: the main loop calls step() and each call
// does at most one short I2C transaction; polls are paced and every wait has a deadline.
//
// Contract:
//  - step(now_us) never blocks and performs at most one I2C transfer. now_us must be the
//    current time of the clock given to the constructor (it schedules; the clock stamps).
//  - Lifecycle: probe (read UNIT_ID 0x16/0x17, must be non-zero) -> reset 0x00 <- 0x00 and
//    wait >= 22 ms for the part to answer again (deadline 100 ms) -> preset writes, one per
//    step, paced like the vendor (1 ms on v3, 100 us on v3HP) -> running.
//    The reset is skipped when addr7 is not 0x62: a reset reloads the default address, so
//    it would move a re-addressed part away from us.
//  - Running: acquire (v3: 0x00 <- 0x04 on every bias_every-th acquisition starting with
//    the first after configuration, 0x03 otherwise; v3HP: 0x00 <- 0x01), poll STATUS 0x01
//    bit0 from Garmin's acquisition time for the preset on, every 200 us until clear (deadline
//    20 ms), read the big-endian distance
//    (v3: pointer 0x8F, STOP before the read; v3HP: 0x0F, repeated start), optionally
//    SIGNAL_STRENGTH 0x0E. Acquisitions are written on a grid of 1 s / rate_hz (a
//    late one does not push the later ones back; after a gap longer than a period the grid
//    restarts), so the achieved rate is rate_hz, or what the part delivers if that is less
//    (max_rate_hz(): Garmin's acquisition time plus one poll interval).
//  - No signal: STATUS bit3 set (sensors.md §2.5), or a distance of 0 or 1 cm. sensors.md
//    documents only bit3; 0 and 1 cm are also treated as "no return" because v3 units are
//    widely reported to output 1 cm without a return and the part cannot range a target
//    that close. Such samples are valid = false, no_signal = true, distance_cm = 0.
//  - Failures: a NACK or bus error on any transfer, or a busy flag still set at the
//    deadline, is counted (i2c_errors / timeouts), and the driver backs off (20 ms doubling
//    to 1 s) and starts over with the probe. A completed configuration after such a failure
//    counts one reinit. Failed probes are not I2C errors: asking whether an absent part is
//    there is not a fault, and an unfitted LIDAR must not fill the error counter.
#pragma once

#include <cstdint>

#include "core/limits.hpp"
#include "hal/hal.hpp"

namespace icgt::core {

// Values match the protocol's LidarModel enum (protocol/messages.toml).
enum class LidarModelKind : uint8_t { v3 = 1, v3hp = 2 };

struct LidarLiteConfig {
  uint8_t addr7 = 0x62;
  LidarModelKind model = LidarModelKind::v3;
  uint8_t preset = 0;         // Garmin configure(cfg): 0..5 on v3, 0..6 on v3HP
  uint16_t rate_hz = 500;     // 1..500
  uint16_t bias_every = 100;  // v3 only: 1 = every acquisition bias-corrected; must be >= 1
  bool read_signal_strength = false;  // one more transaction per sample (register 0x0E)
};

// One acquisition. Flags mirror the protocol's RangeFlags.
struct RangeSample {
  uint64_t acq_start_t_us = 0;  // clock right after the acquire command's transfer returned
  uint64_t read_t_us = 0;       // clock right after the distance read returned (or the failure)
  uint16_t distance_cm = 0;     // 0 unless valid
  uint8_t signal_strength = 0;  // 0 unless read_signal_strength
  bool valid = false;
  bool bias_corrected = false;
  bool no_signal = false;
  bool timeout = false;    // busy flag still set at the deadline
  bool i2c_error = false;  // a transfer of this acquisition failed
};

enum class LidarStep : uint8_t {
  idle,          // nothing in flight (waiting for the next acquisition, absent, backing off)
  busy,          // configuration or an acquisition is in progress
  sample_ready,  // sample() holds a new record; check its flags: an acquisition that started
                 // and then failed (poll / read NACK, busy timeout) is published here too
  error,         // a transfer failed (or the reset deadline passed) with no acquisition
                 // started: probe-to-configure, preset writes, the acquire command itself
};

enum class LidarState : uint8_t {
  disabled,     // constructed with an invalid config: never touches the bus
  absent,       // the last probe was not answered
  configuring,  // reset / preset writes in progress
  running,
  backing_off,  // a transfer failed or timed out; waiting before probing again
};

class LidarLite {
 public:
  static constexpr uint32_t kBusyTimeout_us = 20'000;
  static constexpr uint32_t kPollInterval_us = 200;
  static constexpr uint32_t kResetWait_us = 22'000;
  static constexpr uint32_t kResetDeadline_us = 100'000;
  static constexpr uint32_t kBackoffMin_us = 20'000;
  static constexpr uint32_t kBackoffMax_us = 1'000'000;
  static constexpr uint16_t kMaxRate_hz = limits::kLidarMaxRateHz;

  // An invalid config leaves the driver disabled until reconfigure() succeeds.
  LidarLite(hal::I2cBus& bus, const hal::Clock& clock, const LidarLiteConfig& config);

  [[nodiscard]] LidarStep step(uint64_t now_us);

  // Validates (preset range per model, rate 1..500, bias_every >= 1); on false nothing
  // changes. On true the driver starts over from the probe; counters are kept.
  [[nodiscard]] bool reconfigure(const LidarLiteConfig& config);
  [[nodiscard]] static bool valid(const LidarLiteConfig& config);
  // Garmin's acquisition time for the config's preset (the first STATUS poll waits this).
  [[nodiscard]] static uint32_t expected_conversion_us(const LidarLiteConfig& config);
  // What the part can deliver with this preset: one acquisition plus one poll interval
  // (v3 default preset: 256 Hz; v3HP: 500, the driver's cap). A higher rate_hz is accepted
  // and simply not reached (STATUS reports the achieved rate's samples).
  [[nodiscard]] static uint16_t max_rate_hz(const LidarLiteConfig& config);

  [[nodiscard]] const RangeSample& sample() const { return sample_; }
  [[nodiscard]] const LidarLiteConfig& config() const { return cfg_; }
  [[nodiscard]] LidarState state() const { return state_; }
  // The part answered its most recent transfer and is being configured or is running.
  [[nodiscard]] bool present() const { return state_ == LidarState::configuring || state_ == LidarState::running; }
  [[nodiscard]] bool running() const { return state_ == LidarState::running; }
  [[nodiscard]] uint16_t unit_id() const { return unit_id_; }  // 0 until probed

  [[nodiscard]] uint32_t i2c_errors() const { return i2c_errors_; }
  [[nodiscard]] uint32_t timeouts() const { return timeouts_; }  // busy and reset deadlines missed
  [[nodiscard]] uint16_t reinits() const { return reinits_; }
  [[nodiscard]] uint32_t samples() const { return samples_; }  // records published, failed ones included

 private:
  enum class Phase : uint8_t { off, probe, reset, reset_wait, configure, wait_next, poll, read_distance, read_signal };

  LidarStep do_probe(uint64_t now_us);
  LidarStep do_reset_wait(uint64_t now_us);
  LidarStep do_acquire(uint64_t now_us);
  LidarStep do_poll(uint64_t now_us);
  LidarStep do_read_distance(uint64_t now_us);
  LidarStep do_read_signal(uint64_t now_us);
  LidarStep fail_acquisition(uint64_t now_us, bool timed_out);
  LidarStep publish();
  void back_off(uint64_t now_us);
  void start_over();
  [[nodiscard]] hal::I2cStatus write_reg(uint8_t reg, uint8_t value);
  [[nodiscard]] hal::I2cStatus read_regs(uint8_t reg, uint8_t* out, uint8_t n);

  hal::I2cBus& bus_;
  const hal::Clock& clock_;
  LidarLiteConfig cfg_{};
  uint32_t period_us_ = 0;

  LidarState state_ = LidarState::disabled;
  Phase phase_ = Phase::off;
  uint64_t next_t_us_ = 0;       // earliest time of the phase's next transaction
  uint64_t deadline_t_us_ = 0;   // busy / reset deadline
  uint64_t next_acq_t_us_ = 0;   // next acquisition on the rate grid
  uint8_t config_index_ = 0;
  uint8_t status_ = 0;           // STATUS of the poll that saw busy clear
  uint32_t acquisitions_ = 0;    // since the last configuration, for the bias cadence
  uint8_t failures_in_row_ = 0;  // drives the back-off
  bool configured_once_ = false;
  bool recovering_ = false;
  uint16_t unit_id_ = 0;
  RangeSample current_{};
  RangeSample sample_{};

  uint32_t i2c_errors_ = 0;
  uint32_t timeouts_ = 0;
  uint16_t reinits_ = 0;
  uint32_t samples_ = 0;
};

}  // namespace icgt::core
