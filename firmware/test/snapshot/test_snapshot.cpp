// The exposure's sensor snapshot (core::SensorSnapshot): range interpolated between the acquisitions
// that bracket mid-exposure, else the nearest with its age; none held: invalid; the IMU likewise.
#include <gtest/gtest.h>

#include <cmath>

#include "core/snapshot.hpp"

namespace icgt {
namespace {

using core::SensorSnapshot;
namespace flags = core::snapshot_flags;

core::RangeSample range(uint64_t acq_t_us, uint16_t cm, bool valid = true) {
  core::RangeSample s;
  s.acq_start_t_us = acq_t_us;
  s.read_t_us = acq_t_us + 3'700;
  s.distance_cm = valid ? cm : 0;
  s.valid = valid;
  s.no_signal = !valid;
  return s;
}

// An IMU sample whose read midpoint is t_us: a rotation of `angle_rad` about z, rate `rate_z` [rad/s].
core::ImuSample imu(uint64_t t_us, float angle_rad, float rate_z, uint8_t calib = 0xFF) {
  core::ImuSample s;
  s.read_start_t_us = t_us - 600;
  s.read_end_t_us = t_us + 600;
  s.quat_w = std::cos(angle_rad / 2);
  s.quat_z = std::sin(angle_rad / 2);
  s.gyro_z_rad_s = rate_z;
  s.calib_stat = calib;
  return s;
}

TEST(Snapshot, RangeIsInterpolatedBetweenTheTwoAcquisitionsThatBracketMid) {
  SensorSnapshot snap;
  snap.add_range(range(990'000, 300));
  snap.add_range(range(1'000'000, 400));  // 4.00 m, 2 ms before mid
  snap.add_range(range(1'010'000, 500));  // 5.00 m, 8 ms after mid
  snap.add_range(range(1'020'000, 900));
  const core::Snapshot s = snap.at(1'002'000);
  EXPECT_EQ(s.flags & (flags::range_valid | flags::range_interpolated), flags::range_valid | flags::range_interpolated);
  EXPECT_EQ(s.range_mm, 4'200);  // 4.00 + (5.00 - 4.00) * 2 / 10
  EXPECT_EQ(s.range_age_us, 2'000) << "the nearer of the two";
  EXPECT_EQ(snap.at(1'000'001).range_mm, 4'000) << "rounded to the nearest millimetre";
  EXPECT_EQ(snap.at(1'009'999).range_mm, 5'000);
  EXPECT_EQ(snap.at(1'003'333).range_mm, 4'333);
}

TEST(Snapshot, InvalidAcquisitionsAreSkippedAsTheHostSkipsThem) {
  SensorSnapshot snap;
  snap.add_range(range(1'000'000, 400));
  snap.add_range(range(1'005'000, 0, false));  // no signal: not a zero range
  snap.add_range(range(1'010'000, 500));
  const core::Snapshot s = snap.at(1'005'000);
  EXPECT_TRUE(s.flags & flags::range_interpolated);
  EXPECT_EQ(s.range_mm, 4'500);
  EXPECT_EQ(s.range_age_us, 5'000);
}

TEST(Snapshot, WithoutTheLaterAcquisitionTheNearestIsGivenWithItsAge) {
  SensorSnapshot snap;
  snap.add_range(range(1'000'000, 400));
  snap.add_range(range(1'010'000, 420));
  const core::Snapshot s = snap.at(1'013'500);  // nothing after mid yet
  EXPECT_EQ(s.flags & (flags::range_valid | flags::range_interpolated), flags::range_valid);
  EXPECT_EQ(s.range_mm, 4'200);
  EXPECT_EQ(s.range_age_us, 3'500);
  // Only later acquisitions (mid before anything held): the oldest, its age the other way.
  const core::Snapshot early = snap.at(999'000);
  EXPECT_EQ(early.flags & flags::range_interpolated, 0);
  EXPECT_EQ(early.range_mm, 4'000);
  EXPECT_EQ(early.range_age_us, 1'000);
}

TEST(Snapshot, ABracketWiderThanTheWindowIsNotInterpolatedButTheNearerSideIsUsed) {
  SensorSnapshot snap;
  snap.add_range(range(1'000'000, 400));
  snap.add_range(range(1'070'000, 800));  // 70 ms gap: the LiDAR lost the surface in between
  const core::Snapshot s = snap.at(1'060'000);  // 60 ms after the first, 10 ms before the second
  EXPECT_EQ(s.flags & (flags::range_valid | flags::range_interpolated), flags::range_valid);
  EXPECT_EQ(s.range_mm, 8'000);
  EXPECT_EQ(s.range_age_us, 10'000);
}

TEST(Snapshot, AnAgeBeyondSixtyFiveMillisecondsSaturates) {
  SensorSnapshot snap;
  snap.add_range(range(1'000'000, 400));
  const core::Snapshot s = snap.at(3'000'000);
  EXPECT_TRUE(s.flags & flags::range_valid);
  EXPECT_EQ(s.range_mm, 4'000);
  EXPECT_EQ(s.range_age_us, SensorSnapshot::kAgeSaturated);
}

TEST(Snapshot, NoAcquisitionAtAllMarksTheSnapshotInvalid) {
  SensorSnapshot snap;
  const core::Snapshot none = snap.at(1'000'000);
  EXPECT_EQ(none.flags, 0);
  EXPECT_EQ(none.range_mm, 0);
  EXPECT_EQ(none.range_age_us, 0);
  EXPECT_EQ(none.imu_age_us, 0);
  EXPECT_EQ(none.quat_q14[0], 0);
  snap.add_range(range(999'000, 0, false));  // only failed acquisitions: still nothing to range with
  snap.add_range(range(1'001'000, 0, false));
  EXPECT_EQ(snap.at(1'000'000).flags & flags::range_valid, 0);
  EXPECT_EQ(snap.at(1'000'000).range_mm, 0);
}

TEST(Snapshot, TheRingKeepsTheNewestAcquisitions) {
  SensorSnapshot snap;
  for (uint64_t i = 0; i < 3 * SensorSnapshot::kRangeSlots; ++i) snap.add_range(range(1'000'000 + i * 5'000, 100));
  EXPECT_EQ(snap.ranges_held(), SensorSnapshot::kRangeSlots);
  // Mid long before the oldest kept: the oldest kept, with its (saturated) age.
  const core::Snapshot s = snap.at(1'000'000);
  EXPECT_EQ(s.flags & flags::range_interpolated, 0);
  EXPECT_EQ(s.range_age_us, SensorSnapshot::kAgeSaturated);
}

TEST(Snapshot, ImuIsInterpolatedByNormalisedLerpAndTheRateLinearly) {
  SensorSnapshot snap;
  snap.add_imu(imu(1'000'000, 0.0F, 1.0F, 0x3F));
  snap.add_imu(imu(1'010'000, 0.2F, 2.0F, 0xFF));
  const core::Snapshot s = snap.at(1'007'500);  // 3/4 of the way: nearer the second
  EXPECT_EQ(s.flags & (flags::imu_valid | flags::imu_interpolated), flags::imu_valid | flags::imu_interpolated);
  EXPECT_EQ(s.imu_age_us, 2'500);
  EXPECT_EQ(s.imu_calib_stat, 0xFF) << "the nearer sample's calibration";
  const double angle = 2.0 * std::atan2(s.quat_q14[3] / 16384.0, s.quat_q14[0] / 16384.0);
  EXPECT_NEAR(angle, 0.15, 2e-4);  // nlerp over 0.2 rad is within 1e-4 rad of slerp
  EXPECT_EQ(s.quat_q14[1], 0);
  EXPECT_EQ(s.quat_q14[2], 0);
  EXPECT_EQ(s.gyro_rad900[2], 1'575);  // 1.75 rad/s x 900
}

TEST(Snapshot, TheQuaternionsOtherHemisphereIsTheSameRotation) {
  SensorSnapshot snap;
  core::ImuSample a = imu(1'000'000, 0.1F, 0.0F);
  core::ImuSample b = imu(1'010'000, 0.3F, 0.0F);
  b.quat_w = -b.quat_w;  // -q: the fusion may flip sign between samples
  b.quat_z = -b.quat_z;
  snap.add_imu(a);
  snap.add_imu(b);
  const core::Snapshot s = snap.at(1'005'000);
  const double angle = 2.0 * std::atan2(s.quat_q14[3] / 16384.0, s.quat_q14[0] / 16384.0);
  EXPECT_NEAR(angle, 0.2, 2e-4) << "not the long way round through the identity";
}

TEST(Snapshot, ImuNearestWithAgeAndNoneAtAll) {
  SensorSnapshot snap;
  EXPECT_EQ(snap.at(1'000'000).flags & flags::imu_valid, 0);
  snap.add_imu(imu(1'000'000, 0.5F, -40.0F));  // beyond the i16 rate scale: saturates
  const core::Snapshot s = snap.at(1'004'000);
  EXPECT_EQ(s.flags & (flags::imu_valid | flags::imu_interpolated), flags::imu_valid);
  EXPECT_EQ(s.imu_age_us, 4'000);
  EXPECT_EQ(s.quat_q14[0], static_cast<int16_t>(std::lround(std::cos(0.25) * 16384)));
  EXPECT_EQ(s.gyro_rad900[2], -32'768);
}

TEST(Snapshot, SettledOnceEveryEnabledSensorHasASampleAfterMidOrTheWindowHasPassed) {
  SensorSnapshot snap;
  snap.add_range(range(1'000'000, 400));
  snap.add_imu(imu(1'001'000, 0.0F, 0.0F));
  const uint64_t mid = 1'002'000;
  EXPECT_FALSE(snap.settled(mid, 1'003'000, true, true));
  EXPECT_TRUE(snap.settled(mid, 1'003'000, false, false)) << "sensors off: nothing to wait for";
  snap.add_range(range(1'005'000, 410));
  EXPECT_FALSE(snap.settled(mid, 1'009'000, true, true)) << "the IMU's later sample is still to come";
  EXPECT_TRUE(snap.settled(mid, 1'009'000, true, false));
  snap.add_imu(imu(1'011'000, 0.0F, 0.0F));
  EXPECT_TRUE(snap.settled(mid, 1'012'000, true, true));
  SensorSnapshot silent;
  EXPECT_FALSE(silent.settled(mid, mid + SensorSnapshot::kBracketUs - 1, true, true));
  EXPECT_TRUE(silent.settled(mid, mid + SensorSnapshot::kBracketUs, true, true)) << "a failed sensor holds 50 ms";
}

}  // namespace
}  // namespace icgt
