// The simulated ICGT board: the real firmware App on simulated hardware, in virtual time.
//
// Everything the Teensy has is here as a model: the clock, the I2C bus with a BNO055 and a
// LIDAR-Lite register model, the shutter and focus lines wired to a camera model whose
// flash-sync contact drives the feedback input, an optional GPS PPS input, the RTC and the
// link to the host. run_until() advances virtual time, firing alarms and edges at their exact
// times and running the main loop every loop_period_us, so the same board serves exact unit
// tests and, paced by a real clock, the simulator program.
#pragma once

#include <cstdint>
#include <memory>

#include "board/memory_stream.hpp"
#include "board/sim_gpio.hpp"
#include "board/sim_i2c_bus.hpp"
#include "board/virtual_clock.hpp"
#include "core/app.hpp"
#include "devices/bno055_model.hpp"
#include "devices/camera_model.hpp"
#include "devices/lidar_lite_model.hpp"

namespace icgt::sim {

struct SimBoardConfig {
  core::BoardIdentity identity{proto::Board::simulator, 0x51A0001u, "sim"};
  core::DeviceConfig device{};
  bool bno_fitted = true;
  Bno055ModelConfig bno{};
  bool lidar_fitted = true;
  LidarLiteModelConfig lidar{};
  bool feedback_wired = true;
  CameraModelConfig camera{};
  bool pps_wired = false;
  int64_t rtc_utc_s_at_boot = 1'795'000'000;  // negative: the RTC lost power
  // Main loop cadence without I2C work (an idle Teensy loop is far faster; the loop's own
  // work is not modelled). I2C transfers add their bus time (i2c_timing) to the iteration
  // that makes them, and interrupts due meanwhile fire at their exact times.
  uint32_t loop_period_us = 100;
  I2cTiming i2c_timing{};
  bool i2c_takes_time = true;  // false: transfers take no virtual time (the old model)
};

class SimBoard {
 public:
  SimBoard(const SimBoardConfig& config, hal::ByteStream& link);

  // Boots the firmware (App::begin) at the clock's current time.
  void begin();
  // Runs the device up to device time t_us (never backwards).
  void run_until(uint64_t t_us);
  // A PPS edge pair (rising at t_us, falling 100 ms later) if the PPS input is wired.
  void pps_pulse(uint64_t t_us);

  [[nodiscard]] VirtualClock& clock() { return clock_; }
  [[nodiscard]] core::App& app() { return *app_; }
  [[nodiscard]] SimI2cBus& bus() { return bus_; }
  [[nodiscard]] Bno055Model& bno() { return bno_; }
  [[nodiscard]] LidarLiteModel& lidar() { return lidar_; }
  [[nodiscard]] CameraModel& camera() { return camera_; }
  [[nodiscard]] RecordingDigitalOut& shutter() { return shutter_; }
  [[nodiscard]] RecordingDigitalOut& focus() { return focus_; }
  // Main-loop iterations run so far, and the virtual time they spent [us] (I2C included).
  [[nodiscard]] uint64_t loop_iterations() const { return loop_iterations_; }
  [[nodiscard]] uint64_t loop_busy_us() const { return loop_busy_us_; }

 private:
  // Fires every interrupt due up to t_us in time order, then moves the clock to t_us (the
  // time an I2C transfer blocks the loop: interrupts still run meanwhile, as on the chip).
  void pass_time(uint64_t t_us);
  [[nodiscard]] uint64_t next_irq_t_us() const;
  void fire_next_irq(uint64_t t_us);

  SimBoardConfig cfg_;
  VirtualClock clock_;
  SimI2cBus bus_;
  Bno055Model bno_;
  LidarLiteModel lidar_;
  CameraModel camera_;
  RecordingDigitalOut shutter_;
  RecordingDigitalOut focus_;
  SimEdgeInput feedback_;
  SimEdgeInput pps_;
  VirtualAlarm alarm_;
  SimRtc rtc_;
  std::unique_ptr<core::App> app_;
  std::vector<LineSample> pps_edges_;
  uint64_t next_loop_t_us_ = 0;
  uint64_t loop_iterations_ = 0;
  uint64_t loop_busy_us_ = 0;
};

}  // namespace icgt::sim
