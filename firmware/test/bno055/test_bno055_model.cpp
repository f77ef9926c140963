// The BNO055 register model against the facts of sensors.md §1: the vendor library's begin()
// traffic, identity registers, scaling, status packing, CONFIG-mode behaviour and timing.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include "board/sim_i2c_bus.hpp"
#include "board/virtual_clock.hpp"
#include "devices/bno055_model.hpp"

namespace icgt::sim {
namespace {

using hal::I2cJoin;
using hal::I2cStatus;

constexpr uint8_t kAddr = 0x28;
constexpr uint64_t kMs = 1000;
constexpr double kPi = 3.14159265358979323846;

class Bno055ModelTest : public ::testing::Test {
 protected:
  Bno055ModelTest() { bus_.attach(kAddr, &model_); }

  I2cStatus probe() { return bus_.transfer(kAddr, nullptr, 0, nullptr, 0, I2cJoin::repeated_start); }
  I2cStatus write(uint8_t reg, uint8_t value) {
    const uint8_t buf[2] = {reg, value};
    return bus_.transfer(kAddr, buf, 2, nullptr, 0, I2cJoin::repeated_start);
  }
  I2cStatus read(uint8_t reg, uint8_t* out, std::size_t n, I2cJoin join = I2cJoin::repeated_start) {
    return bus_.transfer(kAddr, &reg, 1, out, n, join);
  }
  uint8_t read8(uint8_t reg) {
    uint8_t v = 0xEE;
    EXPECT_EQ(read(reg, &v, 1), I2cStatus::ok) << "reg 0x" << std::hex << int{reg};
    return v;
  }
  int16_t read16(uint8_t reg) {
    uint8_t b[2] = {};
    EXPECT_EQ(read(reg, b, 2), I2cStatus::ok);
    return static_cast<int16_t>(static_cast<uint16_t>(b[0] | (b[1] << 8)));
  }
  void boot() { clock_.set_us(700 * kMs); }
  // Booted, then into a mode with the switch time elapsed.
  void enter_mode(uint8_t mode) {
    boot();
    ASSERT_EQ(write(0x3D, mode), I2cStatus::ok);
    clock_.advance_us(30 * kMs);
  }

  VirtualClock clock_;
  SimI2cBus bus_{clock_};
  Bno055Model model_;
};

TEST_F(Bno055ModelTest, AdafruitBeginSequenceIsAcknowledgedAndChipIdReturnsAfterReset) {
  bus_.set_recording(true);
  // 1. probe every 10 ms for up to 850 ms.
  uint64_t first_ack_us = 0;
  for (int i = 0; i < 85 && first_ack_us == 0; ++i) {
    if (probe() == I2cStatus::ok) {
      first_ack_us = clock_.now_us();
    } else {
      EXPECT_LT(clock_.now_us(), 650 * kMs) << "NACK after the boot time";
      clock_.advance_us(10 * kMs);
    }
  }
  ASSERT_GE(first_ack_us, 650 * kMs);
  bus_.clear_transactions();

  EXPECT_EQ(read8(0x00), 0xA0);                   // 2. CHIP_ID
  ASSERT_EQ(write(0x3D, 0x00), I2cStatus::ok);    // 3. CONFIG
  clock_.advance_us(30 * kMs);
  ASSERT_EQ(write(0x3F, 0x20), I2cStatus::ok);    // 4. RST_SYS
  const uint64_t reset_t_us = clock_.now_us();
  clock_.advance_us(30 * kMs);
  const std::size_t before_poll = bus_.transactions().size();

  // 5. poll CHIP_ID every 10 ms: reads inside the reset window NACK.
  int nacks = 0;
  bool back = false;
  for (int i = 0; i < 200 && !back; ++i) {
    uint8_t id = 0;
    const I2cStatus st = read(0x00, &id, 1);
    if (st == I2cStatus::ok && id == 0xA0) {
      back = true;
      EXPECT_GE(clock_.now_us() - reset_t_us, 650 * kMs);
    } else {
      EXPECT_EQ(st, I2cStatus::nack_address);
      EXPECT_LT(clock_.now_us() - reset_t_us, 650 * kMs);
      ++nacks;
      clock_.advance_us(10 * kMs);
    }
  }
  ASSERT_TRUE(back);
  EXPECT_GT(nacks, 50);
  const std::size_t after_poll = bus_.transactions().size();
  clock_.advance_us(50 * kMs);
  ASSERT_EQ(write(0x3E, 0x00), I2cStatus::ok);  // 6. PWR_MODE normal
  clock_.advance_us(10 * kMs);
  ASSERT_EQ(write(0x07, 0x00), I2cStatus::ok);  // 7. PAGE_ID
  ASSERT_EQ(write(0x3F, 0x00), I2cStatus::ok);  // 8. SYS_TRIGGER
  clock_.advance_us(10 * kMs);
  ASSERT_EQ(write(0x3D, 0x0C), I2cStatus::ok);  // 9. NDOF
  clock_.advance_us(50 * kMs);

  const auto& log = bus_.transactions();
  for (std::size_t i = 0; i < log.size(); ++i) {
    if (i >= before_poll && i < after_poll - 1) continue;  // the expected NACKs of step 5
    EXPECT_EQ(log[i].status, I2cStatus::ok) << "transaction " << i;
  }
  EXPECT_EQ(read8(0x3D) & 0x0F, 0x0C);
  EXPECT_EQ(read8(0x39), 5) << "SYS_STATUS: fusion running";
  EXPECT_EQ(model_.last_join(), I2cJoin::repeated_start);
  EXPECT_EQ(model_.resets(), 1U);
}

TEST_F(Bno055ModelTest, NacksItsAddressUntilBootTimeHasPassed) {
  EXPECT_EQ(probe(), I2cStatus::nack_address);
  clock_.set_us(649 * kMs);
  EXPECT_EQ(probe(), I2cStatus::nack_address);
  uint8_t v = 0;
  EXPECT_EQ(read(0x00, &v, 1), I2cStatus::nack_address);
  clock_.set_us(650 * kMs);
  EXPECT_EQ(probe(), I2cStatus::ok);
}

TEST_F(Bno055ModelTest, IdentityRegistersReadInOneAutoIncrementingBurst) {
  boot();
  uint8_t b[8] = {};
  ASSERT_EQ(read(0x00, b, 8), I2cStatus::ok);
  EXPECT_EQ(b[0], 0xA0);
  EXPECT_EQ(b[1], 0xFB);
  EXPECT_EQ(b[2], 0x32);
  EXPECT_EQ(b[3], 0x0F);
  EXPECT_EQ(b[4] | (b[5] << 8), 0x0311);  // SW_REV_ID (configurable)
  EXPECT_EQ(b[6], 0x15);                  // BL_REV_ID (configurable)
  EXPECT_EQ(b[7], 0x00);                  // PAGE_ID
}

TEST_F(Bno055ModelTest, AcceptsStopOrRepeatedStartBetweenPointerAndRead) {
  boot();
  uint8_t v = 0;
  ASSERT_EQ(read(0x00, &v, 1, I2cJoin::stop), I2cStatus::ok);
  EXPECT_EQ(v, 0xA0);
  EXPECT_EQ(model_.last_join(), I2cJoin::stop);
  // Pointer write in one transaction, read in the next (read-only transfer).
  const uint8_t ptr = 0x01;
  ASSERT_EQ(bus_.transfer(kAddr, &ptr, 1, nullptr, 0, I2cJoin::stop), I2cStatus::ok);
  ASSERT_EQ(bus_.transfer(kAddr, nullptr, 0, &v, 1, I2cJoin::stop), I2cStatus::ok);
  EXPECT_EQ(v, 0xFB);
}

TEST_F(Bno055ModelTest, ScalingMatchesAdafruitConversions) {
  Bno055Truth t;
  t.euler_deg = std::array<double, 3>{360.0, 0.0, 0.0};
  t.quat_wxyz = {1.0, 0.0, 0.0, 0.0};
  t.accel_m_s2 = {-9.81, 0.0, 0.0};
  t.temp_c = -30.0;
  model_.set_truth(t);
  enter_mode(0x0C);

  const int16_t heading = read16(0x1A);
  const int16_t qw = read16(0x20);
  const int16_t ax = read16(0x08);
  const uint8_t temp = read8(0x34);
  EXPECT_EQ(heading, 5760);
  EXPECT_EQ(qw, 16384);
  EXPECT_EQ(ax, -981);
  EXPECT_EQ(temp, 0xE2);
  // The library's divisors: 16 LSB/deg, 2^14 LSB, 100 LSB per m/s^2, signed byte.
  EXPECT_DOUBLE_EQ(heading / 16.0, 360.0);
  EXPECT_DOUBLE_EQ(qw / 16384.0, 1.0);
  EXPECT_DOUBLE_EQ(ax / 100.0, -9.81);
  EXPECT_EQ(static_cast<int8_t>(temp), -30);
}

TEST_F(Bno055ModelTest, DefaultUnitsAreMetresPerSecondSquaredDpsDegreesCelsius) {
  Bno055Truth t;
  t.gyro_rad_s = {1.0, -0.5, 0.0};
  t.quat_wxyz = {std::cos(kPi / 4), 0.0, 0.0, std::sin(kPi / 4)};  // 90 deg yaw
  t.temp_c = 31.0;
  model_.set_truth(t);
  enter_mode(0x0C);
  EXPECT_EQ(read8(0x3B), 0x80);
  EXPECT_EQ(read16(0x14), 917);   // 57.2958 dps * 16
  EXPECT_EQ(read16(0x16), -458);
  EXPECT_EQ(read16(0x1A), 1440);  // heading 90 deg
  EXPECT_EQ(read8(0x34), 31);
}

TEST_F(Bno055ModelTest, UnitSelRadiansMilliGAndFahrenheitChangeTheScaling) {
  Bno055Truth t;
  t.gyro_rad_s = {1.0, 0.0, 0.0};
  t.accel_m_s2 = {9.80665, 0.0, 0.0};
  t.euler_deg = std::array<double, 3>{180.0, 0.0, 0.0};
  t.temp_c = -10.0;
  model_.set_truth(t);
  boot();
  ASSERT_EQ(write(0x3B, 0x80 | 0x01 | 0x02 | 0x04 | 0x10), I2cStatus::ok);
  ASSERT_EQ(write(0x3D, 0x0C), I2cStatus::ok);
  clock_.advance_us(30 * kMs);
  EXPECT_EQ(read16(0x14), 900);   // rad/s: 900 LSB
  EXPECT_EQ(read16(0x08), 1000);  // mg: 1 LSB
  EXPECT_EQ(read16(0x1A), 2827);  // pi rad * 900
  EXPECT_EQ(read8(0x34), 28);     // 14 F * 2
}

TEST_F(Bno055ModelTest, CalibStatPacksSysGyrAccMagFromHighBits) {
  Bno055Truth t;
  t.calib_sys = 3;
  t.calib_gyr = 2;
  t.calib_acc = 1;
  t.calib_mag = 0;
  model_.set_truth(t);
  enter_mode(0x0C);
  EXPECT_EQ(read8(0x35), 0xE4);
  t.calib_sys = 0;
  t.calib_gyr = 3;
  t.calib_acc = 1;
  t.calib_mag = 0;
  model_.set_truth(t);
  EXPECT_EQ(read8(0x35), 0x34);  // the bench unit's reading
  EXPECT_EQ(Bno055Model::calib_stat(0, 3, 0, 3), 0x33);
}

TEST_F(Bno055ModelTest, OprModeReadsReservedBitAtPowerUpAndTheModeAloneAfterWrites) {
  boot();
  EXPECT_EQ(read8(0x3D), 0x10);
  EXPECT_EQ(read8(0x3D) & 0x0F, 0x00);
  ASSERT_EQ(write(0x3D, 0x08), I2cStatus::ok);
  EXPECT_EQ(read8(0x3D), 0x08);  // reserved bits replaced by the write (datasheet), as on a part
  ASSERT_EQ(write(0x3D, 0x0F), I2cStatus::ok);  // not a mode: ignored
  EXPECT_EQ(read8(0x3D), 0x08);
  ASSERT_EQ(write(0x3D, 0x00), I2cStatus::ok);
  ASSERT_EQ(write(0x3D, 0x0C), I2cStatus::ok);
  EXPECT_EQ(read8(0x3D), 0x0C);  // what Adafruit's getMode() returns in NDOF: 0x0C, not 0x1C
}

TEST_F(Bno055ModelTest, DataRegistersReadZeroInConfigAndDuringModeSwitch) {
  Bno055Truth t;
  t.quat_wxyz = {0.5, 0.5, 0.5, 0.5};
  t.gyro_rad_s = {0.1, 0.2, 0.3};
  t.lin_accel_m_s2 = {1.0, 2.0, 3.0};
  t.temp_c = 31.0;
  model_.set_truth(t);
  boot();
  auto all_zero = [this] {
    uint8_t a[18] = {};
    uint8_t b[28] = {};
    EXPECT_EQ(read(0x08, a, sizeof a), I2cStatus::ok);
    EXPECT_EQ(read(0x1A, b, sizeof b), I2cStatus::ok);
    for (uint8_t v : a) {
      if (v != 0) return false;
    }
    for (uint8_t v : b) {
      if (v != 0) return false;
    }
    return true;
  };
  EXPECT_TRUE(all_zero());
  EXPECT_EQ(read8(0x39), 0) << "SYS_STATUS idle in CONFIG";
  ASSERT_EQ(write(0x3D, 0x0C), I2cStatus::ok);
  clock_.advance_us(6 * kMs);  // CONFIG -> NDOF takes 7 ms
  EXPECT_TRUE(all_zero());
  clock_.advance_us(1 * kMs);
  EXPECT_FALSE(all_zero());
  EXPECT_EQ(read8(0x34), 31);
  EXPECT_EQ(read8(0x39), 5);
  ASSERT_EQ(write(0x3D, 0x00), I2cStatus::ok);
  EXPECT_TRUE(all_zero());
  EXPECT_EQ(read8(0x34), 0) << "TEMP reads 0 in CONFIG";
}

TEST_F(Bno055ModelTest, ImuPlusProducesFusionWithoutMagnetometer) {
  enter_mode(0x08);
  EXPECT_EQ(read16(0x0E), 0);
  EXPECT_EQ(read16(0x20), 16384);
  EXPECT_EQ(read16(0x0C), 981);  // gravity on z
  EXPECT_EQ(read8(0x39), 5);
}

TEST_F(Bno055ModelTest, NonFusionModeHasSensorDataButNoFusionOutputs) {
  enter_mode(0x07);  // AMG
  EXPECT_EQ(read16(0x0C), 981);
  EXPECT_EQ(read16(0x20), 0);
  EXPECT_EQ(read8(0x39), 6);
}

TEST_F(Bno055ModelTest, OffsetPairLatchesOnlyWhenItsMsbIsWritten) {
  boot();
  ASSERT_EQ(write(0x55, 0x34), I2cStatus::ok);
  EXPECT_EQ(read8(0x55), 0x00) << "LSB alone must not take effect";
  ASSERT_EQ(write(0x56, 0x12), I2cStatus::ok);
  EXPECT_EQ(read16(0x55), 0x1234);
  // MAG radius, the last pair, as a two-byte burst.
  const uint8_t burst[3] = {0x69, 0xE0, 0x01};
  ASSERT_EQ(bus_.transfer(kAddr, burst, 3, nullptr, 0, I2cJoin::repeated_start), I2cStatus::ok);
  EXPECT_EQ(read16(0x69), 0x01E0);
}

TEST_F(Bno055ModelTest, ConfigRegistersIgnoreWritesOutsideConfigMode) {
  enter_mode(0x0C);
  ASSERT_EQ(write(0x3B, 0x01), I2cStatus::ok);
  ASSERT_EQ(write(0x56, 0x12), I2cStatus::ok);
  ASSERT_EQ(write(0x3F, 0x80), I2cStatus::ok);
  EXPECT_EQ(read8(0x3B), 0x80);
  EXPECT_EQ(read8(0x56), 0x00);
  EXPECT_FALSE(model_.ext_crystal());
}

TEST_F(Bno055ModelTest, ReadOnlyAndUndefinedRegistersIgnoreWritesAndReadZero) {
  enter_mode(0x0C);
  const int16_t qw = read16(0x20);
  ASSERT_EQ(write(0x00, 0x55), I2cStatus::ok);
  ASSERT_EQ(write(0x20, 0x00), I2cStatus::ok);
  ASSERT_EQ(write(0x3C, 0x77), I2cStatus::ok);
  ASSERT_EQ(write(0x70, 0x77), I2cStatus::ok);
  EXPECT_EQ(read8(0x00), 0xA0);
  EXPECT_EQ(read16(0x20), qw);
  EXPECT_EQ(read8(0x3C), 0x00);
  EXPECT_EQ(read8(0x70), 0x00);
  EXPECT_EQ(read8(0x90), 0x00);
}

TEST_F(Bno055ModelTest, AxisMapPowersUpAsPlacementP1) {
  boot();
  EXPECT_EQ(read8(0x41), 0x24);
  EXPECT_EQ(read8(0x42), 0x00);
  EXPECT_EQ(read8(0x36), 0x0F) << "ST_RESULT: all self-tests passed";
}

TEST_F(Bno055ModelTest, PageOneHidesPageZeroRegisters) {
  boot();
  ASSERT_EQ(write(0x07, 0x01), I2cStatus::ok);
  EXPECT_EQ(read8(0x07), 0x01);
  EXPECT_NE(read8(0x00), 0xA0);
  ASSERT_EQ(write(0x07, 0x00), I2cStatus::ok);
  EXPECT_EQ(read8(0x00), 0xA0);
}

TEST_F(Bno055ModelTest, ExternalCrystalSelectIsRecordedInConfigAndClearedByReset) {
  boot();
  ASSERT_EQ(write(0x3F, 0x80), I2cStatus::ok);
  EXPECT_TRUE(model_.ext_crystal());
  EXPECT_EQ(read8(0x3F), 0x80);
  ASSERT_EQ(write(0x3F, 0x20), I2cStatus::ok);
  clock_.advance_us(650 * kMs);
  EXPECT_FALSE(model_.ext_crystal());
}

TEST_F(Bno055ModelTest, SoftResetNacksForResetTimeThenRestoresDefaultsInConfig) {
  enter_mode(0x0C);
  ASSERT_EQ(write(0x3D, 0x00), I2cStatus::ok);
  clock_.advance_us(20 * kMs);
  ASSERT_EQ(write(0x3B, 0x06), I2cStatus::ok);
  ASSERT_EQ(write(0x3D, 0x0C), I2cStatus::ok);
  clock_.advance_us(20 * kMs);
  ASSERT_EQ(write(0x3F, 0x20), I2cStatus::ok);
  clock_.advance_us(649 * kMs);
  EXPECT_EQ(probe(), I2cStatus::nack_address);
  clock_.advance_us(1 * kMs);
  EXPECT_EQ(probe(), I2cStatus::ok);
  EXPECT_EQ(read8(0x3D), 0x10);
  EXPECT_EQ(read8(0x3B), 0x80);
  EXPECT_EQ(read16(0x20), 0);
}

TEST_F(Bno055ModelTest, InjectedResetAndPowerCycleTakeThePartAwayAtTheirTime) {
  enter_mode(0x0C);
  const uint64_t t0 = clock_.now_us();
  model_.reset_at(t0 + 5 * kMs);
  model_.power_cycle(t0 + 2000 * kMs, 100 * kMs);
  EXPECT_EQ(read16(0x20), 16384);
  clock_.set_us(t0 + 5 * kMs);
  EXPECT_EQ(probe(), I2cStatus::nack_address);
  clock_.set_us(t0 + 655 * kMs);
  EXPECT_EQ(probe(), I2cStatus::ok);
  EXPECT_EQ(read8(0x3D), 0x10);
  EXPECT_EQ(read16(0x20), 0);
  EXPECT_EQ(model_.resets(), 1U);
  clock_.set_us(t0 + 2749 * kMs);  // off 100 ms + boot 650 ms
  EXPECT_EQ(probe(), I2cStatus::nack_address);
  clock_.set_us(t0 + 2750 * kMs);
  EXPECT_EQ(probe(), I2cStatus::ok);
  EXPECT_EQ(model_.resets(), 2U);
}

TEST_F(Bno055ModelTest, OutputsChangeAtTheHundredHertzDataRate) {
  Bno055ModelConfig cfg;
  cfg.noise.accel_m_s2 = 0.05;
  Bno055Model noisy(cfg);
  bus_.attach(kAddr, &noisy);
  enter_mode(0x0C);
  const int16_t a0 = read16(0x08);
  clock_.advance_us(5 * kMs);
  EXPECT_EQ(read16(0x08), a0) << "same 10 ms output period, same data";
  int changes = 0;
  int16_t prev = a0;
  for (int i = 0; i < 20; ++i) {
    clock_.advance_us(10 * kMs);
    const int16_t a = read16(0x08);
    changes += a != prev ? 1 : 0;
    prev = a;
  }
  EXPECT_GT(changes, 10);
}

TEST(Bno055ModelNoise, SameSeedGivesSameNoise) {
  Bno055ModelConfig cfg;
  cfg.noise = {0.01, 0.01, 0.1, 1.0};
  cfg.seed = 42;
  std::vector<uint8_t> out[2];
  for (auto& o : out) {
    VirtualClock clock;
    SimI2cBus bus(clock);
    Bno055Model model(cfg);
    bus.attach(kAddr, &model);
    clock.set_us(700 * kMs);
    const uint8_t mode[2] = {0x3D, 0x0C};
    ASSERT_EQ(bus.transfer(kAddr, mode, 2, nullptr, 0, I2cJoin::repeated_start), I2cStatus::ok);
    for (int i = 0; i < 10; ++i) {
      clock.advance_us(10 * kMs);
      uint8_t reg = 0x08;
      uint8_t b[32] = {};
      ASSERT_EQ(bus.transfer(kAddr, &reg, 1, b, sizeof b, I2cJoin::repeated_start), I2cStatus::ok);
      o.insert(o.end(), b, b + sizeof b);
    }
  }
  EXPECT_EQ(out[0], out[1]);
}

TEST(Bno055ModelAddress, AnswersOnlyOnTheAddressItIsAttachedAt) {
  VirtualClock clock(700 * kMs);
  SimI2cBus bus(clock);
  Bno055Model model;
  bus.attach(0x29, &model);
  EXPECT_EQ(bus.transfer(0x29, nullptr, 0, nullptr, 0, I2cJoin::repeated_start), I2cStatus::ok);
  EXPECT_EQ(bus.transfer(0x28, nullptr, 0, nullptr, 0, I2cJoin::repeated_start), I2cStatus::nack_address);
}

}  // namespace
}  // namespace icgt::sim
