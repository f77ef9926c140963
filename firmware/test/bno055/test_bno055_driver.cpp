// The BNO055 driver against the register model on the simulated bus, in virtual time: the
// main loop is a 1 ms tick that calls step() and never lets the driver hold it up.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "board/sim_i2c_bus.hpp"
#include "board/virtual_clock.hpp"
#include "core/bno055.hpp"
#include "devices/bno055_model.hpp"

namespace icgt {
namespace {

using core::Bno055;
using core::Bno055Config;
using core::Bno055State;
using core::Bno055Step;
using core::ImuSample;
using hal::I2cJoin;
using hal::I2cStatus;
using sim::Bno055Model;
using sim::Bno055ModelConfig;
using sim::Bno055Truth;

constexpr uint8_t kAddr = 0x28;
constexpr uint64_t kMs = 1000;
constexpr uint64_t kTickUs = 1000;
// Init writes or reads one register per call; a sample is two bursts.
constexpr uint64_t kMaxTransfersPerStep = 2;

// Charges each transfer its bus time, so sample stamps span the reads as on hardware.
class TimedBus final : public hal::I2cBus {
 public:
  TimedBus(hal::I2cBus& inner, sim::VirtualClock& clock, uint64_t per_transfer_us)
      : inner_(inner), clock_(clock), per_transfer_us_(per_transfer_us) {}
  [[nodiscard]] I2cStatus transfer(uint8_t addr7, const uint8_t* send, std::size_t send_len, uint8_t* recv,
                                   std::size_t recv_len, I2cJoin join) override {
    const I2cStatus st = inner_.transfer(addr7, send, send_len, recv, recv_len, join);
    clock_.advance_us(per_transfer_us_);
    return st;
  }

 private:
  hal::I2cBus& inner_;
  sim::VirtualClock& clock_;
  uint64_t per_transfer_us_;
};

struct Rig {
  explicit Rig(const Bno055Config& config = {}, const Bno055ModelConfig& model_config = {}, bool attach = true,
               uint64_t per_transfer_us = 0)
      : model(model_config), timed(bus, clock, per_transfer_us),
        imu(per_transfer_us > 0 ? static_cast<hal::I2cBus&>(timed) : bus, clock, config) {
    if (attach) bus.attach(kAddr, &model);
    bus.set_recording(true);
  }

  // One main-loop pass: step, then let 1 ms of virtual time go by.
  Bno055Step tick() {
    const uint64_t transfers_before = bus.transfer_count();
    const uint64_t t_us = clock.now_us();
    const Bno055Step r = imu.step(t_us);
    const uint64_t transfers = bus.transfer_count() - transfers_before;
    max_transfers_per_step = std::max(max_transfers_per_step, transfers);
    if (r == Bno055Step::idle) {
      EXPECT_EQ(transfers, 0U) << "idle step touched the bus";
    }
    if (r == Bno055Step::sample_ready) samples.push_back(imu.sample());
    if (r == Bno055Step::error) error_t_us.push_back(t_us);
    states.push_back(imu.state());
    clock.set_us(t_us + kTickUs);
    return r;
  }
  // Ticks until pred() holds or limit_us of virtual time passed; returns pred().
  bool run_until(const std::function<bool()>& pred, uint64_t limit_us) {
    const uint64_t end_us = clock.now_us() + limit_us;
    while (!pred() && clock.now_us() < end_us) (void)tick();
    return pred();
  }
  void run_for(uint64_t dt_us) {
    const uint64_t end_us = clock.now_us() + dt_us;
    while (clock.now_us() < end_us) (void)tick();
  }
  bool seen(Bno055State s) const { return std::find(states.begin(), states.end(), s) != states.end(); }
  // Register writes (reg, value) in bus order.
  std::vector<std::pair<uint8_t, uint8_t>> writes() const {
    std::vector<std::pair<uint8_t, uint8_t>> w;
    for (const auto& t : bus.transactions()) {
      if (t.written.size() == 2 && t.read_len == 0 && t.status == I2cStatus::ok) w.emplace_back(t.written[0], t.written[1]);
    }
    return w;
  }

  sim::VirtualClock clock;
  sim::SimI2cBus bus{clock};
  Bno055Model model;
  TimedBus timed;
  Bno055 imu;
  std::vector<ImuSample> samples;
  std::vector<uint64_t> error_t_us;
  std::vector<Bno055State> states;
  uint64_t max_transfers_per_step = 0;
};

TEST(Bno055Driver, InitFromPowerOnRunsTheVendorSequenceAndEntersNdof) {
  Rig rig;
  EXPECT_EQ(rig.imu.state(), Bno055State::initialising);
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  // Boot 650 ms + reset 650 ms + the settle times: well under the 3 s limit.
  EXPECT_GE(rig.clock.now_us(), 1'300 * kMs);
  EXPECT_LT(rig.clock.now_us(), 1'600 * kMs);
  const std::vector<std::pair<uint8_t, uint8_t>> expected = {
      {0x3D, 0x00}, {0x3F, 0x20}, {0x3E, 0x00}, {0x07, 0x00}, {0x3F, 0x00}, {0x3D, 0x0C}};
  EXPECT_EQ(rig.writes(), expected);
  EXPECT_EQ(rig.model.mode(), 0x0C);
  EXPECT_FALSE(rig.model.ext_crystal());
  EXPECT_TRUE(rig.imu.present());
  EXPECT_EQ(rig.imu.i2c_errors(), 0U);
  EXPECT_EQ(rig.imu.reinits(), 0U);
  EXPECT_LE(rig.max_transfers_per_step, kMaxTransfersPerStep);
}

TEST(Bno055Driver, ExternalCrystalOptionSetsClkSelBeforeTheFusionMode) {
  Bno055Config cfg;
  cfg.ext_crystal = true;
  Rig rig(cfg);
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  EXPECT_TRUE(rig.model.ext_crystal());
  const auto w = rig.writes();
  ASSERT_GE(w.size(), 2U);
  EXPECT_EQ(w[w.size() - 2], std::make_pair(uint8_t{0x3F}, uint8_t{0x80}));
}

TEST(Bno055Driver, ImuPlusModeRunsAndProducesSamples) {
  Bno055Config cfg;
  cfg.opr_mode = 0x08;
  Rig rig(cfg);
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() >= 10; }, 3'000 * kMs));
  EXPECT_EQ(rig.model.mode(), 0x08);
  EXPECT_NEAR(rig.samples.back().quat_w, 1.0F, 1e-4F);
}

TEST(Bno055Driver, SamplesAtHundredHertzCarryTheTruthWithinQuantisation) {
  Rig rig;
  Bno055Truth t;
  const double half = 0.3;  // rotation of 0.6 rad about a tilted axis
  t.quat_wxyz = {std::cos(half), std::sin(half) * 0.6, std::sin(half) * 0.0, std::sin(half) * 0.8};
  t.gyro_rad_s = {0.5, -1.25, 3.0};
  t.accel_m_s2 = {1.5, -2.25, 9.0};
  t.lin_accel_m_s2 = {0.4, -0.3, 0.2};
  t.temp_c = 31.0;
  t.calib_sys = 0;
  t.calib_gyr = 3;
  t.calib_acc = 1;
  t.calib_mag = 0;
  rig.model.set_truth(t);
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  rig.samples.clear();
  rig.run_for(1'000 * kMs);
  EXPECT_GE(rig.samples.size(), 99U);
  EXPECT_LE(rig.samples.size(), 101U);

  constexpr float kQuatTol = 1.0F / 16384.0F;
  constexpr float kGyroTol = 0.5F / 16.0F * 3.14159265F / 180.0F + 1e-6F;
  constexpr float kAccelTol = 0.005F + 1e-5F;
  const ImuSample& s = rig.samples.back();
  EXPECT_NEAR(s.quat_w, t.quat_wxyz[0], kQuatTol);
  EXPECT_NEAR(s.quat_x, t.quat_wxyz[1], kQuatTol);
  EXPECT_NEAR(s.quat_y, t.quat_wxyz[2], kQuatTol);
  EXPECT_NEAR(s.quat_z, t.quat_wxyz[3], kQuatTol);
  EXPECT_NEAR(s.gyro_x_rad_s, 0.5F, kGyroTol);
  EXPECT_NEAR(s.gyro_y_rad_s, -1.25F, kGyroTol);
  EXPECT_NEAR(s.gyro_z_rad_s, 3.0F, kGyroTol);
  EXPECT_NEAR(s.accel_x_m_s2, 1.5F, kAccelTol);
  EXPECT_NEAR(s.accel_y_m_s2, -2.25F, kAccelTol);
  EXPECT_NEAR(s.accel_z_m_s2, 9.0F, kAccelTol);
  EXPECT_NEAR(s.lin_accel_x_m_s2, 0.4F, kAccelTol);
  EXPECT_NEAR(s.lin_accel_y_m_s2, -0.3F, kAccelTol);
  EXPECT_NEAR(s.lin_accel_z_m_s2, 0.2F, kAccelTol);
  EXPECT_EQ(s.temp_c, 31);
  EXPECT_EQ(s.calib_stat, 0x34);

  EXPECT_TRUE(rig.samples[0].reinitialised);
  // The schedule is anchored to due times: after the first (served a tick late) it is exact.
  for (std::size_t i = 2; i < rig.samples.size(); ++i) {
    EXPECT_EQ(rig.samples[i].read_start_t_us - rig.samples[i - 1].read_start_t_us, 10 * kMs);
  }
  for (std::size_t i = 1; i < rig.samples.size(); ++i) EXPECT_FALSE(rig.samples[i].reinitialised);
  // Data bursts only: 2 per sample, nothing else on the bus while running.
  EXPECT_LE(rig.max_transfers_per_step, kMaxTransfersPerStep);
}

TEST(Bno055Driver, SampleIsStampedWithTheStartAndEndOfItsReads) {
  Rig rig({}, {}, true, 600);  // ~22 bytes at 400 kHz
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() >= 5; }, 5'000 * kMs));
  for (const ImuSample& s : rig.samples) {
    EXPECT_LE(s.read_start_t_us, s.read_end_t_us);
    EXPECT_EQ(s.read_end_t_us - s.read_start_t_us, 2 * 600U);
  }
  EXPECT_TRUE(rig.samples.front().reinitialised) << "the first sample after init is flagged";
  EXPECT_FALSE(rig.samples.back().reinitialised);
}

TEST(Bno055Driver, ConfiguredRateIsKept) {
  Bno055Config cfg;
  cfg.rate_hz = 25;
  Rig rig(cfg);
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  rig.samples.clear();
  rig.run_for(1'000 * kMs);
  EXPECT_GE(rig.samples.size(), 24U);
  EXPECT_LE(rig.samples.size(), 26U);
}

TEST(Bno055Driver, ReconfiguringTheRateKeepsRunningButANewModeReinitialises) {
  Rig rig;
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  Bno055Config cfg;
  cfg.rate_hz = 50;
  ASSERT_TRUE(rig.imu.reconfigure(cfg));
  EXPECT_TRUE(rig.imu.running());
  cfg.rate_hz = 0;
  EXPECT_FALSE(rig.imu.reconfigure(cfg));
  EXPECT_EQ(rig.imu.config().rate_hz, 50);
  cfg.rate_hz = 50;
  cfg.opr_mode = 0x08;
  ASSERT_TRUE(rig.imu.reconfigure(cfg));
  EXPECT_EQ(rig.imu.state(), Bno055State::initialising);
  rig.samples.clear();
  ASSERT_TRUE(rig.run_until([&] { return !rig.samples.empty(); }, 3'000 * kMs));
  EXPECT_EQ(rig.model.mode(), 0x08);
  EXPECT_TRUE(rig.samples.front().reinitialised);
  EXPECT_EQ(rig.imu.reinits(), 0U) << "a requested re-init is not a failure";
}

TEST(Bno055Driver, InvalidConfigsAreRejected) {
  EXPECT_TRUE(Bno055::valid({}));
  EXPECT_TRUE(Bno055::valid({0x29, 0x08, true, 1}));
  EXPECT_FALSE(Bno055::valid({0x30, 0x0C, false, 100}));
  EXPECT_FALSE(Bno055::valid({0x28, 0x00, false, 100})) << "CONFIG has no quaternion";
  EXPECT_FALSE(Bno055::valid({0x28, 0x07, false, 100})) << "AMG has no fusion";
  EXPECT_FALSE(Bno055::valid({0x28, 0x0C, false, 0}));
  EXPECT_FALSE(Bno055::valid({0x28, 0x0C, false, 101}));
}

TEST(Bno055Driver, InitRidesThroughNackedProbesWithoutCountingThem) {
  Bno055ModelConfig mcfg;
  mcfg.boot_time_us = 0;
  Rig rig({}, mcfg);
  rig.bus.fail_next(kAddr, 5);
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  EXPECT_EQ(rig.imu.i2c_errors(), 0U) << "address NACKs while the part may boot are expected";
  EXPECT_EQ(rig.imu.reinits(), 0U);
}

TEST(Bno055Driver, BusTimeoutsDuringProbeAreCountedButInitStillCompletes) {
  Bno055ModelConfig mcfg;
  mcfg.boot_time_us = 0;
  Rig rig({}, mcfg);
  rig.bus.fail_next(kAddr, 3, I2cStatus::timeout);
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  EXPECT_EQ(rig.imu.i2c_errors(), 3U);
  EXPECT_EQ(rig.imu.reinits(), 0U);
}

TEST(Bno055Driver, NackDuringConfigurationBacksOffAndReinitialises) {
  Rig rig;
  // Fail the write after PWR_MODE (PAGE_ID) once.
  ASSERT_TRUE(rig.run_until(
      [&] {
        const auto w = rig.writes();
        return !w.empty() && w.back() == std::make_pair(uint8_t{0x3E}, uint8_t{0x00});
      },
      3'000 * kMs));
  rig.bus.fail_next(kAddr, 1, I2cStatus::nack_data);
  ASSERT_TRUE(rig.run_until([&] { return !rig.error_t_us.empty(); }, 100 * kMs));
  EXPECT_EQ(rig.imu.state(), Bno055State::backing_off);
  EXPECT_EQ(rig.imu.i2c_errors(), 1U);
  ASSERT_TRUE(rig.run_until([&] { return !rig.samples.empty(); }, 3'000 * kMs));
  EXPECT_EQ(rig.imu.reinits(), 1U);
  EXPECT_TRUE(rig.samples.front().reinitialised);
  EXPECT_LE(rig.max_transfers_per_step, kMaxTransfersPerStep);
}

TEST(Bno055Driver, AbsentPartNeverBlocksBacksOffExponentiallyAndReportsAbsent) {
  Rig rig({}, {}, /*attach=*/false);
  rig.run_for(30'000 * kMs);
  EXPECT_EQ(rig.imu.state(), Bno055State::absent);
  EXPECT_FALSE(rig.imu.present());
  EXPECT_FALSE(rig.imu.running());
  EXPECT_TRUE(rig.samples.empty());
  EXPECT_EQ(rig.imu.i2c_errors(), 0U);
  EXPECT_EQ(rig.imu.reinits(), 0U);
  EXPECT_LE(rig.max_transfers_per_step, 1U);
  // Each attempt probes for 1 s; the gaps between attempts double from 100 ms to 5 s.
  ASSERT_GE(rig.error_t_us.size(), 6U);
  std::vector<uint64_t> backoff_us;
  for (std::size_t i = 1; i < rig.error_t_us.size(); ++i) {
    backoff_us.push_back(rig.error_t_us[i] - rig.error_t_us[i - 1] - 1'000 * kMs);
  }
  EXPECT_NEAR(static_cast<double>(backoff_us[0]), 100'000.0, 2'000.0);
  EXPECT_NEAR(static_cast<double>(backoff_us[1]), 200'000.0, 2'000.0);
  EXPECT_NEAR(static_cast<double>(backoff_us[2]), 400'000.0, 2'000.0);
  EXPECT_NEAR(static_cast<double>(backoff_us.back()), 5'000'000.0, 2'000.0);

  // Plugged in later: found at the next attempt, without counting as a re-init.
  rig.bus.attach(kAddr, &rig.model);
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 10'000 * kMs));
  EXPECT_TRUE(rig.imu.present());
  EXPECT_EQ(rig.imu.reinits(), 0U);
}

TEST(Bno055Driver, MidRunResetIsDetectedByNackAndReinitialised) {
  Rig rig;
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() >= 10; }, 3'000 * kMs));
  rig.model.reset_at(rig.clock.now_us() + 1 * kMs);  // 650 ms away from the bus
  const std::size_t before = rig.samples.size();
  ASSERT_TRUE(rig.run_until([&] { return !rig.error_t_us.empty(); }, 100 * kMs));
  EXPECT_EQ(rig.imu.state(), Bno055State::backing_off);
  EXPECT_TRUE(rig.imu.present());
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() > before; }, 5'000 * kMs));
  EXPECT_TRUE(rig.seen(Bno055State::initialising));
  EXPECT_EQ(rig.imu.reinits(), 1U);
  EXPECT_EQ(rig.imu.i2c_errors(), 1U);
  EXPECT_TRUE(rig.samples[before].reinitialised);
  EXPECT_EQ(rig.model.mode(), 0x0C);
  EXPECT_LE(rig.max_transfers_per_step, kMaxTransfersPerStep);
}

TEST(Bno055Driver, QuickResetIsDetectedByZeroQuaternionAndConfirmedByOprMode) {
  Bno055ModelConfig mcfg;
  mcfg.reset_time_us = 2 * kMs;  // back before the next read: only the data give it away
  Rig rig({}, mcfg);
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() >= 10; }, 3'000 * kMs));
  rig.model.reset_at(rig.samples.back().read_end_t_us + 1 * kMs);
  const std::size_t before = rig.samples.size();
  rig.bus.clear_transactions();
  ASSERT_TRUE(rig.run_until([&] { return !rig.error_t_us.empty(); }, 100 * kMs));
  // The zero-quaternion read is followed by a single OPR_MODE read.
  bool confirmed = false;
  for (const auto& t : rig.bus.transactions()) {
    confirmed = confirmed || (t.written.size() == 1 && t.written[0] == 0x3D && t.read_len == 1 &&
                              t.status == I2cStatus::ok && (t.read[0] & 0x0F) == 0x00);
  }
  EXPECT_TRUE(confirmed);
  EXPECT_EQ(rig.imu.i2c_errors(), 0U);
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() > before; }, 5'000 * kMs));
  EXPECT_EQ(rig.imu.reinits(), 1U);
  EXPECT_TRUE(rig.samples[before].reinitialised);
  for (std::size_t i = 0; i < rig.samples.size(); ++i) EXPECT_NE(rig.samples[i].quat_w, 0.0F) << i;
}

TEST(Bno055Driver, PowerCycleWhileRunningRecoversAfterTheBoot) {
  Rig rig;
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() >= 10; }, 3'000 * kMs));
  rig.model.power_cycle(rig.clock.now_us(), 2'000 * kMs);  // unplugged for 2 s
  const std::size_t before = rig.samples.size();
  ASSERT_TRUE(rig.run_until([&] { return rig.samples.size() > before; }, 20'000 * kMs));
  EXPECT_TRUE(rig.seen(Bno055State::absent)) << "a probe phase ran out while it was unplugged";
  EXPECT_EQ(rig.imu.reinits(), 1U);
  EXPECT_TRUE(rig.samples[before].reinitialised);
  EXPECT_LE(rig.max_transfers_per_step, kMaxTransfersPerStep);
}

TEST(Bno055Driver, StepReturnsAtOnceAndIsIdleUntilItsNextTime) {
  Rig rig;
  ASSERT_TRUE(rig.run_until([&] { return rig.imu.running(); }, 3'000 * kMs));
  (void)rig.run_until([&] { return !rig.samples.empty(); }, 100 * kMs);
  const uint64_t next_us = rig.imu.next_step_t_us();
  EXPECT_GT(next_us, rig.clock.now_us() - kTickUs);
  const uint64_t transfers = rig.bus.transfer_count();
  EXPECT_EQ(rig.imu.step(next_us - 1), Bno055Step::idle);
  EXPECT_EQ(rig.bus.transfer_count(), transfers);
  EXPECT_EQ(rig.imu.step(next_us), Bno055Step::sample_ready);
  EXPECT_EQ(rig.bus.transfer_count(), transfers + 2);
}

}  // namespace
}  // namespace icgt
