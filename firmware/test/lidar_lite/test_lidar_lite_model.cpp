// The LIDAR-Lite register model against shared/reference/sensors.md §2, driven with raw
// bus transfers (no driver), so the model is checked independently of the code it tests.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "board/sim_i2c_bus.hpp"
#include "board/virtual_clock.hpp"
#include "devices/lidar_lite_model.hpp"

namespace icgt::sim {
namespace {

using hal::I2cJoin;
using hal::I2cStatus;

constexpr uint8_t kAddr = 0x62;

class LidarLiteModelTest : public ::testing::Test {
 protected:
  explicit LidarLiteModelTest(const LidarLiteModelConfig& cfg = {}) : model(cfg) { bus.attach(kAddr, &model); }

  I2cStatus write(std::vector<uint8_t> bytes) { return bus.transfer(kAddr, bytes.data(), bytes.size(), nullptr, 0, I2cJoin::stop); }

  std::vector<uint8_t> read(uint8_t pointer, std::size_t n, I2cJoin join = I2cJoin::stop) {
    std::vector<uint8_t> out(n, 0xEE);
    EXPECT_EQ(bus.transfer(kAddr, &pointer, 1, out.data(), n, join), I2cStatus::ok);
    return out;
  }

  uint8_t status() { return read(0x01, 1)[0]; }
  uint16_t distance_v3() {
    const auto d = read(0x8F, 2);
    return static_cast<uint16_t>((d[0] << 8) | d[1]);
  }

  // Starts a v3 acquisition without bias correction and waits it out.
  void measure() {
    ASSERT_EQ(write({0x00, 0x03}), I2cStatus::ok);
    clock.advance_us(model.conversion_time_us(false));
  }

  VirtualClock clock{1'000'000};
  SimI2cBus bus{clock};
  LidarLiteModel model;
};

class LidarLiteModelV3hpTest : public LidarLiteModelTest {
 protected:
  LidarLiteModelV3hpTest() : LidarLiteModelTest(hp()) {}
  static LidarLiteModelConfig hp() {
    LidarLiteModelConfig c;
    c.variant = LidarLiteVariant::v3hp;
    return c;
  }
};

TEST_F(LidarLiteModelTest, PresetRegistersWrittenWithRegValueBurstAreStored) {
  ASSERT_EQ(write({0x02, 0x1D}), I2cStatus::ok);
  ASSERT_EQ(write({0x04, 0x00}), I2cStatus::ok);
  ASSERT_EQ(write({0x1C, 0xB0}), I2cStatus::ok);
  EXPECT_EQ(read(0x02, 1)[0], 0x1D);
  EXPECT_EQ(read(0x04, 1)[0], 0x00);
  EXPECT_EQ(read(0x1C, 1)[0], 0xB0);
}

TEST_F(LidarLiteModelTest, PowersUpWithDatasheetDefaults) {
  EXPECT_EQ(read(0x02, 1)[0], 0x80);
  EXPECT_EQ(read(0x04, 1)[0], 0x08);
  EXPECT_EQ(read(0x12, 1)[0], 0x05);
  EXPECT_EQ(read(0x1C, 1)[0], 0x00);
}

TEST_F(LidarLiteModelTest, PointerOnlyWriteChangesNoRegister) {
  // Pre-2018 parts took "pointer" then "data" as two bursts; the new FPGA reads the second
  // burst's byte as a new pointer, so nothing is written.
  ASSERT_EQ(write({0x02}), I2cStatus::ok);
  ASSERT_EQ(write({0x1D}), I2cStatus::ok);
  EXPECT_EQ(model.pointer_only_writes(), 2u);
  EXPECT_EQ(read(0x02, 1)[0], 0x80);
  EXPECT_EQ(model.reg(0x1D), 0x00);
  EXPECT_EQ(model.acquisitions(), 0u);
}

TEST_F(LidarLiteModelTest, UndefinedRegisterReadsZeroAndIgnoresWrites) {
  EXPECT_EQ(read(0x03, 1)[0], 0x00);
  EXPECT_EQ(read(0x7E, 1)[0], 0x00);
  ASSERT_EQ(write({0x03, 0x55}), I2cStatus::ok);
  EXPECT_EQ(read(0x03, 1)[0], 0x00);
  EXPECT_EQ(model.ignored_writes(), 1u);
}

TEST_F(LidarLiteModelTest, ReadOnlyUnitIdIsNonZeroAndIgnoresWrites) {
  const auto id = read(0x96, 2);
  EXPECT_NE((id[0] << 8) | id[1], 0);
  ASSERT_EQ(write({0x16, 0x00}), I2cStatus::ok);
  EXPECT_EQ(read(0x96, 2), id);
}

TEST_F(LidarLiteModelTest, AcquisitionSetsBusyThenLatchesBigEndianDistance) {
  model.set_range_cm(1234.0);  // 0x04D2
  ASSERT_EQ(write({0x00, 0x04}), I2cStatus::ok);
  EXPECT_EQ(status() & 0x01, 0x01);
  clock.advance_us(model.conversion_time_us(true) - 1);
  EXPECT_EQ(status() & 0x01, 0x01);
  clock.advance_us(1);
  EXPECT_EQ(status() & 0x09, 0x00);
  EXPECT_EQ(read(0x8F, 2), (std::vector<uint8_t>{0x04, 0xD2}));
  EXPECT_EQ(read(0x0F, 1)[0], 0x04);
  EXPECT_EQ(read(0x10, 1)[0], 0xD2);
}

TEST_F(LidarLiteModelTest, WhileBusyDistanceReadsReturnPreviousResult) {
  model.set_range_cm(300.0);
  measure();
  model.set_range_cm(700.0);
  ASSERT_EQ(write({0x00, 0x03}), I2cStatus::ok);
  clock.advance_us(model.conversion_time_us(false) / 2);
  ASSERT_EQ(status() & 0x01, 0x01);
  EXPECT_EQ(distance_v3(), 300);
  EXPECT_EQ(read(0x0F, 1)[0], 0x01);  // 300 = 0x012C, byte by byte too
  EXPECT_EQ(read(0x10, 1)[0], 0x2C);
  clock.advance_us(model.conversion_time_us(false));
  EXPECT_EQ(distance_v3(), 700);
}

TEST_F(LidarLiteModelTest, RangeIsSampledWhenTheCommandArrives) {
  model.set_range_cm(300.0);
  ASSERT_EQ(write({0x00, 0x03}), I2cStatus::ok);
  model.set_range_cm(900.0);
  clock.advance_us(model.conversion_time_us(false));
  EXPECT_EQ(distance_v3(), 300);
}

TEST_F(LidarLiteModelTest, V3ReadWithoutAutoIncrementFlagRepeatsTheRegister) {
  model.set_range_cm(1234.0);
  measure();
  EXPECT_EQ(read(0x0F, 2), (std::vector<uint8_t>{0x04, 0x04}));
}

TEST_F(LidarLiteModelV3hpTest, AutoIncrementsWithoutFlagAndTreats0x8FAsUndefined) {
  model.set_range_cm(1234.0);
  ASSERT_EQ(write({0x00, 0x01}), I2cStatus::ok);
  clock.advance_us(model.conversion_time_us(false));
  EXPECT_EQ(read(0x0F, 2, I2cJoin::repeated_start), (std::vector<uint8_t>{0x04, 0xD2}));
  EXPECT_EQ(read(0x8F, 2, I2cJoin::repeated_start), (std::vector<uint8_t>{0x00, 0x00}));
}

TEST_F(LidarLiteModelTest, AcceptsStopAndRepeatedStartBetweenPointerAndData) {
  EXPECT_EQ(read(0x02, 1, I2cJoin::stop)[0], 0x80);
  EXPECT_EQ(read(0x02, 1, I2cJoin::repeated_start)[0], 0x80);
  EXPECT_EQ(model.stop_joins(), 1u);
  EXPECT_EQ(model.repeated_start_joins(), 1u);
}

TEST_F(LidarLiteModelTest, V3MeasuresOn0x03And0x04ButNotOnTheV3hpCommand) {
  ASSERT_EQ(write({0x00, 0x01}), I2cStatus::ok);
  EXPECT_EQ(model.acquisitions(), 0u);
  EXPECT_EQ(status() & 0x01, 0x00);
  ASSERT_EQ(write({0x00, 0x04}), I2cStatus::ok);
  clock.advance_us(5'000);
  ASSERT_EQ(write({0x00, 0x03}), I2cStatus::ok);
  EXPECT_EQ(model.bias_corrected_acquisitions(), 1u);
  EXPECT_EQ(model.uncorrected_acquisitions(), 1u);
}

TEST_F(LidarLiteModelV3hpTest, MeasuresOnlyOn0x01) {
  ASSERT_EQ(write({0x00, 0x04}), I2cStatus::ok);
  EXPECT_EQ(model.acquisitions(), 0u);
  ASSERT_EQ(write({0x00, 0x01}), I2cStatus::ok);
  EXPECT_EQ(model.acquisitions(), 1u);
  EXPECT_EQ(read(0x01, 1, I2cJoin::repeated_start)[0] & 0x01, 0x01);
}

TEST_F(LidarLiteModelTest, CountsBiasCorrectedAcquisitionsSeparately) {
  for (int i = 0; i < 200; ++i) {
    ASSERT_EQ(write({0x00, static_cast<uint8_t>(i % 100 == 0 ? 0x04 : 0x03)}), I2cStatus::ok);
    clock.advance_us(4'000);  // past the 3.7 ms (3.9 ms bias-corrected) acquisition
  }
  EXPECT_EQ(model.acquisitions(), 200u);
  EXPECT_EQ(model.bias_corrected_acquisitions(), 2u);
  EXPECT_EQ(model.uncorrected_acquisitions(), 198u);
  EXPECT_EQ(model.commands_while_busy(), 0u);
}

TEST_F(LidarLiteModelTest, ResetReloadsDefaultsAndNacksForAbout22ms) {
  model.set_range_cm(321.0);
  measure();
  ASSERT_EQ(write({0x02, 0xFF}), I2cStatus::ok);
  ASSERT_EQ(write({0x00, 0x00}), I2cStatus::ok);
  EXPECT_EQ(model.resets(), 1u);
  uint8_t b = 0;
  const uint8_t p = 0x02;
  EXPECT_EQ(bus.transfer(kAddr, nullptr, 0, nullptr, 0, I2cJoin::stop), I2cStatus::nack_address);
  clock.advance_us(21'999);
  EXPECT_EQ(bus.transfer(kAddr, &p, 1, &b, 1, I2cJoin::stop), I2cStatus::nack_address);
  clock.advance_us(1);
  EXPECT_EQ(read(0x02, 1)[0], 0x80);
  EXPECT_EQ(distance_v3(), 0);
}

TEST_F(LidarLiteModelTest, NoSignalLatchesStatusBit3Distance1AndZeroStrength) {
  model.set_no_signal(true);
  measure();
  EXPECT_EQ(status() & 0x09, 0x08);
  EXPECT_EQ(distance_v3(), 1);
  EXPECT_EQ(read(0x0E, 1)[0], 0);
  model.set_no_signal(false);
  model.set_range_cm(250.0);
  measure();
  EXPECT_EQ(status() & 0x08, 0x00);
  EXPECT_EQ(distance_v3(), 250);
  EXPECT_EQ(read(0x0E, 1)[0], model.config().signal_strength);
}

TEST_F(LidarLiteModelTest, V3StatusCarriesHealthBitSoDriversMustMask) { EXPECT_EQ(status(), 0x20); }

TEST(LidarLiteModelNoise, SeededNoiseIsRepeatableAndHasTheRequestedSpread) {
  auto run = [](uint64_t seed) {
    LidarLiteModelConfig cfg;
    cfg.noise_sigma_cm = 5.0;
    cfg.seed = seed;
    VirtualClock clock{1'000'000};  // long past the power-up NACK window
    SimI2cBus bus(clock);
    LidarLiteModel model(cfg);
    bus.attach(kAddr, &model);
    model.set_range_cm(1000.0);
    std::vector<int> d;
    for (int i = 0; i < 2000; ++i) {
      const uint8_t cmd[2] = {0x00, 0x03};
      EXPECT_EQ(bus.transfer(kAddr, cmd, 2, nullptr, 0, I2cJoin::stop), I2cStatus::ok);
      clock.advance_us(4'000);
      uint8_t p = 0x8F, out[2] = {};
      EXPECT_EQ(bus.transfer(kAddr, &p, 1, out, 2, I2cJoin::stop), I2cStatus::ok);
      d.push_back((out[0] << 8) | out[1]);
    }
    return d;
  };
  const auto a = run(7), b = run(7), c = run(8);
  EXPECT_EQ(a, b);
  EXPECT_NE(a, c);
  double sum = 0, sq = 0;
  for (int v : a) {
    sum += v;
    sq += static_cast<double>(v) * v;
  }
  const double mean = sum / a.size();
  const double sd = std::sqrt(sq / a.size() - mean * mean);
  EXPECT_NEAR(mean, 1000.0, 0.5);
  EXPECT_NEAR(sd, 5.0, 0.5);
}

TEST_F(LidarLiteModelTest, MaxRangePresetConvertsLongerThanDefault) {
  const uint32_t default_us = model.conversion_time_us(false);
  ASSERT_EQ(write({0x02, 0xFF}), I2cStatus::ok);
  EXPECT_GT(model.conversion_time_us(false), default_us * 3 / 2);
  ASSERT_EQ(write({0x02, 0x1D}), I2cStatus::ok);
  EXPECT_LT(model.conversion_time_us(false), default_us);
}

TEST_F(LidarLiteModelTest, PowerCycleNacksThenBootsWithDefaults) {
  ASSERT_EQ(write({0x02, 0xFF}), I2cStatus::ok);
  model.power_cycle_at(clock.now_us() + 1'000, 50'000);
  clock.advance_us(999);
  EXPECT_EQ(read(0x02, 1)[0], 0xFF);
  clock.advance_us(1);
  EXPECT_EQ(write({}), I2cStatus::nack_address);
  clock.advance_us(50'000 + 22'000 - 1);
  EXPECT_EQ(write({}), I2cStatus::nack_address);
  clock.advance_us(1);
  EXPECT_EQ(read(0x02, 1)[0], 0x80);
  EXPECT_GE(model.nacks(), 2u);
}

TEST_F(LidarLiteModelTest, StuckBusyHoldsBusyFlagAndLatchesNothing) {
  model.set_range_cm(300.0);
  measure();
  model.set_stuck_busy(true);
  model.set_range_cm(600.0);
  ASSERT_EQ(write({0x00, 0x03}), I2cStatus::ok);
  clock.advance_us(1'000'000);
  EXPECT_EQ(status() & 0x01, 0x01);
  EXPECT_EQ(distance_v3(), 300);
  ASSERT_EQ(write({0x00, 0x00}), I2cStatus::ok);  // a reset does not cure a broken part
  clock.advance_us(22'000);
  EXPECT_EQ(status() & 0x01, 0x01);
  model.set_stuck_busy(false);
  EXPECT_EQ(status() & 0x01, 0x00);
}

TEST(LidarLiteModelTiming, AcquisitionTimesAreGarminsFiguresAndThePartNacksWhilePoweringUp) {
  VirtualClock clock;
  SimI2cBus bus(clock);
  LidarLiteModel v3;  // defaults: v3, powered at t = 0
  bus.attach(kAddr, &v3);
  uint8_t id[2] = {};
  const uint8_t pointer = 0x96;
  // Booting for reset_us after power-up: every transfer is NACKed.
  EXPECT_EQ(bus.transfer(kAddr, &pointer, 1, id, 2, I2cJoin::stop), I2cStatus::nack_address);
  clock.set_us(v3.config().reset_us - 1);
  EXPECT_EQ(bus.transfer(kAddr, &pointer, 1, id, 2, I2cJoin::stop), I2cStatus::nack_address);
  clock.set_us(v3.config().reset_us);
  EXPECT_EQ(bus.transfer(kAddr, &pointer, 1, id, 2, I2cJoin::stop), I2cStatus::ok);
  // v3 manual: 270 Hz typical at the default count 0x80, 650 Hz "fast mode" (0x1D).
  EXPECT_EQ(v3.conversion_time_us(false), 3'700u);
  EXPECT_NEAR(1e6 / v3.conversion_time_us(false), 270.0, 5.0);
  const uint8_t fast[2] = {0x02, 0x1D};
  ASSERT_EQ(bus.transfer(kAddr, fast, 2, nullptr, 0, I2cJoin::stop), I2cStatus::ok);
  EXPECT_NEAR(1e6 / v3.conversion_time_us(false), 650.0, 15.0);
  // v3HP manual: greater than 1 kHz.
  LidarLiteModelConfig hp;
  hp.variant = LidarLiteVariant::v3hp;
  const LidarLiteModel v3hp(hp);
  EXPECT_GT(1e6 / v3hp.conversion_time_us(false), 1000.0);
}

}  // namespace
}  // namespace icgt::sim
