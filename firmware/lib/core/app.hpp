// The ICGT device application: everything the firmware does, on any board.
//
// Composition roots (the Teensy's src/main.cpp, the simulator, tests) build the board's
// HAL objects, hand them to App in AppPorts, call begin() once and poll() forever. App owns
// the trigger, exposure pairing, timebase, sensor drivers, the command decoder and the
// outbox. poll() never blocks: each call does a bounded amount of I2C and serial work;
// shots are fired by the trigger's alarm interrupt, never by poll().
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/bno055.hpp"
#include "core/exposure_pairing.hpp"
#include "core/host_watchdog.hpp"
#include "core/lidar_lite.hpp"
#include "core/outbox.hpp"
#include "core/snapshot.hpp"
#include "core/time_sync_responder.hpp"
#include "core/timebase.hpp"
#include "core/trigger.hpp"
#include "frame.hpp"
#include "hal/hal.hpp"

namespace icgt::core {

struct AppPorts {
  const hal::Clock& clock;
  hal::ByteStream& link;
  hal::I2cBus& i2c;
  hal::Alarm& trigger_alarm;
  hal::DigitalOut& shutter;
  hal::DigitalOut& focus;
  hal::EdgeInput* feedback;  // camera hot-shoe / flash sync; null if not wired
  hal::EdgeInput* pps;       // GPS pulse per second; null if not wired
  hal::Rtc& rtc;
};

struct BoardIdentity {
  proto::Board board = proto::Board::unknown;
  uint32_t serial_number = 0;
  const char* firmware_version = "0.0.0";
};

// What the device does until the host sends CONFIGURE.
struct DeviceConfig {
  uint16_t imu_rate_hz = 100;
  uint8_t imu_mode = 0x0C;  // NDOF
  bool imu_ext_crystal = false;
  // A v3 at its default preset delivers ~230-256 Hz (3.7 ms acquisitions, Garmin: 270 Hz typical,
  // less the polls and the loop): 200 Hz is met every time (test_app AppTiming tests).
  uint16_t range_rate_hz = 200;
  proto::LidarModel lidar_model = proto::LidarModel::v3;
  uint8_t lidar_preset = 0;
  uint16_t lidar_bias_every = 100;
  uint8_t polarity = proto::PinPolarity::focus_active_high | proto::PinPolarity::shutter_active_high |
                     proto::PinPolarity::pps_rising;  // feedback active low: hot shoes pull down
  bool feedback_enabled = true;                        // when the board wires the line
  uint32_t feedback_timeout_us = 0;  // 0 = derived from the interval at each capture (limits.hpp)
  uint32_t feedback_min_lag_us = 0;  // the camera's shortest shutter lag
};

class App {
 public:
  static constexpr uint64_t kStatusPeriodUs = 1'000'000;
  // After a host opens the port the device holds its output this long: hosts flush their
  // input buffer while opening (pyserial does, after raising DTR), which would silently eat
  // whatever the device sent in that window, HELLO and queued exposures included.
  static constexpr uint64_t kLinkSettleUs = 100'000;
  static constexpr std::size_t kRxChunkBytes = 64;
  // Exposures waiting for the samples after their mid-exposure (their sensor snapshot, snapshot.hpp):
  // at most SensorSnapshot::kBracketUs each, so 8 covers 20 shots/s with room. A full hold sends the
  // oldest at once with what the snapshot has then.
  static constexpr std::size_t kHeldExposures = 8;
  // I2C budget: the sensor drivers' transfers block the loop (Wire waits for the bus), so
  // they may take at most this share of the loop's time in the long run. A credit of bus time
  // grows at kI2cSharePercent of the time that passes (capped at kI2cBurstUs) and each sensor
  // step spends what its transfer took; a sensor is stepped only while the credit is
  // positive. Over any window T the loop spends at most T * 25 % + kI2cBurstUs + one
  // transfer on I2C: with a stuck bus (16 ms per failed transfer on both Teensy cores) that
  // is one transfer per 64 ms instead of a loop stalled 16 ms out of every 16. The default
  // sensors (BNO055 at 100 Hz, LIDAR-Lite v3 at 200 Hz) use about 18 % on a 400 kHz bus
  // (the simulator's bus timing: test_app AppTiming.DefaultRangeRateIsDelivered...).
  static constexpr uint32_t kI2cSharePercent = 25;
  static constexpr uint32_t kI2cBurstUs = 2'000;

  App(const AppPorts& ports, const BoardIdentity& identity, const DeviceConfig& config = {});
  App(const App&) = delete;
  App& operator=(const App&) = delete;

  // Once, after the board is up: anchors the timebase and queues HELLO.
  void begin();
  // One main-loop iteration.
  void poll();

  [[nodiscard]] const Trigger& trigger() const { return trigger_; }
  [[nodiscard]] const Outbox& outbox() const { return outbox_; }
  [[nodiscard]] const Bno055& imu() const { return imu_; }
  [[nodiscard]] const LidarLite& lidar() const { return lidar_; }
  [[nodiscard]] const Timebase& timebase() const { return timebase_; }
  [[nodiscard]] const SensorSnapshot& snapshot() const { return snapshot_; }
  [[nodiscard]] std::size_t held_exposures() const { return held_count_; }
  [[nodiscard]] const DeviceConfig& config() const { return config_; }
  [[nodiscard]] const proto::DecoderStats& rx_stats() const { return rx_.stats(); }
  [[nodiscard]] const HostWatchdog& host_watchdog() const { return watchdog_; }
  // Why the last capture ended, and when (DEVICE_STATE); none / 0 while one runs or before the first.
  [[nodiscard]] proto::StopCause stop_cause() const { return stop_cause_; }
  [[nodiscard]] uint64_t stopped_t_us() const { return stopped_t_us_; }
  [[nodiscard]] proto::Status status(uint64_t now_us);
  // What a (re)connecting host needs to take over: sent after every HELLO.
  [[nodiscard]] proto::DeviceState device_state(uint64_t now_us) const;
  // Time the sensor steps held the loop (I2C transfers), and steps deferred by the budget.
  [[nodiscard]] uint64_t i2c_busy_us() const { return i2c_busy_us_; }
  [[nodiscard]] uint64_t i2c_deferred_steps() const { return i2c_deferred_steps_; }

 private:
  void receive(uint64_t now_us);
  void on_frame(uint64_t rx_t_us);
  void on_rejected_frame();
  void ack(proto::ErrorCode code, uint32_t detail = 0);
  // Both set `limit` to the limit a refusal broke (ACK.detail), none otherwise.
  [[nodiscard]] proto::ErrorCode start_capture(const proto::StartCapture& cmd, uint64_t now_us, proto::Limit& limit);
  [[nodiscard]] proto::ErrorCode configure(const proto::Configure& cmd, proto::Limit& limit);
  // Ends a capture whose host went silent (HostWatchdog) and notes one that finished by itself.
  void watch_capture(uint64_t now_us);
  void end_capture(proto::StopCause cause, uint64_t now_us);
  void step_sensors(uint64_t now_us);
  [[nodiscard]] bool i2c_credit_left(uint64_t now_us);
  void spend_i2c(uint64_t from_us);
  void drain_exposures(uint64_t now_us);
  // Sends the held exposures whose snapshot is settled, oldest first (mids are in order, so are deadlines).
  void release_exposures(uint64_t now_us);
  // Fills the oldest held exposure's snapshot from what is held now and queues it.
  void send_held_front();
  void drain_pps();
  void report_sensor_states(uint64_t now_us);
  void send_hello(uint64_t now_us);
  void log(uint64_t now_us, proto::LogLevel level, const char* text, uint32_t number = 0, bool with_number = false);

  const AppPorts ports_;
  const BoardIdentity identity_;
  DeviceConfig config_;
  Trigger trigger_;
  ExposurePairing pairing_;
  Timebase timebase_;
  Bno055 imu_;
  LidarLite lidar_;
  Outbox outbox_;
  TimeSyncResponder time_sync_;
  SensorSnapshot snapshot_;
  struct HeldExposure {
    proto::Exposure msg;
    uint64_t mid_us;
  };
  HeldExposure held_[kHeldExposures]{};
  std::size_t held_head_ = 0;
  std::size_t held_count_ = 0;
  HostWatchdog watchdog_;
  proto::StreamDecoder rx_;

  bool imu_enabled_;
  bool lidar_enabled_;
  bool link_up_ = false;
  uint64_t send_after_t_us_ = 0;
  uint64_t next_status_t_us_ = 0;
  uint32_t loop_max_us_ = 0;
  int64_t i2c_credit_us_ = kI2cBurstUs;
  uint64_t i2c_credit_t_us_ = 0;
  uint64_t i2c_busy_us_ = 0;
  uint64_t i2c_deferred_steps_ = 0;
  proto::StartCapture capture_{};  // the last capture started (DEVICE_STATE)
  uint32_t capture_start_seq_ = 0;
  uint32_t host_received_seq_ = 0;
  bool host_received_valid_ = false;
  uint32_t recording_id_ = 0;  // the last HOST_RECEIVED's
  bool capture_running_ = false;  // a capture started and has not been seen to end yet
  proto::StopCause stop_cause_ = proto::StopCause::none;
  uint64_t stopped_t_us_ = 0;
  Bno055State last_imu_state_ = Bno055State::initialising;
  LidarState last_lidar_state_ = LidarState::configuring;
};

}  // namespace icgt::core
