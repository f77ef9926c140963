// The sensor snapshot an EXPOSURE carries (protocol version 2, SnapshotFlags): the LiDAR range and
// the BNO055 orientation and rate at mid-exposure, from the samples the device read around it.
//
// Why on the device: the history keeps exposures for minutes (one event slot each) but IMU and range
// samples for seconds. After a long outage the host gets the exposure back without the samples that
// would have ranged and oriented it; the snapshot, stored in the exposure's own slot, survives as long
// as the exposure does.
//
// Rules (SPEC.md §"EXPOSURE's sensor snapshot"), the host's own for its samples (icgt.geotag.geotagger):
//  - range: the valid acquisitions (keyed on acq_start_t_us) nearest mid at or before it and at or after
//    it. Both in and each within kBracketUs of mid: interpolated linearly, `range_interpolated`, the age
//    the nearer one's distance to mid. Otherwise the nearest one with its age. None kept: range invalid.
//  - IMU: the same with the samples' read midpoints; the quaternion interpolated by normalised lerp (the
//    two sample's hemispheres aligned), the rate linearly; calib_stat of the nearer one.
//  - ages saturate at kAgeSaturated (65.535 ms).
// Ring depth: kRangeSlots valid acquisitions (0.32 s at 200 Hz, 0.64 s at 100 Hz) and kImuSlots IMU
// samples (0.32 s at 100 Hz): enough for an exposure emitted by its feedback end or by the derived
// feedback timeout. An exposure emitted later (a 2 s feedback timeout) gets the nearest sample held,
// with its true age.
//
// No heap, no clock: times are parameters.
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/bno055.hpp"
#include "core/lidar_lite.hpp"

namespace icgt::core {

// The protocol's SnapshotFlags bits (pinned in snapshot.cpp).
namespace snapshot_flags {
inline constexpr uint8_t range_valid = 1u << 0;
inline constexpr uint8_t range_interpolated = 1u << 1;
inline constexpr uint8_t imu_valid = 1u << 2;
inline constexpr uint8_t imu_interpolated = 1u << 3;
}  // namespace snapshot_flags

// The EXPOSURE snapshot fields, in their wire units.
struct Snapshot {
  uint8_t flags = 0;
  uint16_t range_mm = 0;
  uint16_t range_age_us = 0;
  uint16_t imu_age_us = 0;
  uint8_t imu_calib_stat = 0;
  int16_t quat_q14[4]{};     // w, x, y, z; 16384 = 1
  int16_t gyro_rad900[3]{};  // x, y, z; 900 = 1 rad/s
};

class SensorSnapshot {
 public:
  static constexpr uint64_t kBracketUs = 50'000;  // the host's default range_stale_ms
  static constexpr uint16_t kAgeSaturated = 0xFFFF;
  static constexpr std::size_t kRangeSlots = 64;
  static constexpr std::size_t kImuSlots = 32;

  // Every acquisition the LiDAR driver completes; only valid ones are kept.
  void add_range(const RangeSample& s);
  // Every IMU sample the BNO055 driver delivers.
  void add_imu(const ImuSample& s);
  // Forget everything (a sensor re-initialised into another configuration is not a reason: samples
  // stay true; this is for tests and a reboot of the core).
  void clear();

  // True when nothing still to come can change the snapshot at mid_us: each enabled sensor has a
  // sample at or after mid, or now_us is kBracketUs past mid (a later one would not be used).
  [[nodiscard]] bool settled(uint64_t mid_us, uint64_t now_us, bool range_on, bool imu_on) const;
  [[nodiscard]] Snapshot at(uint64_t mid_us) const;

  [[nodiscard]] std::size_t ranges_held() const { return range_count_; }
  [[nodiscard]] std::size_t imu_held() const { return imu_count_; }

 private:
  struct RangeEntry {
    uint64_t t_us;
    uint16_t range_mm;
  };
  struct ImuEntry {  // in the wire's units: 24 bytes, not 40 with floats (the Teensy 3.6 counts every KiB)
    uint64_t t_us;
    int16_t quat_q14[4];
    int16_t gyro_rad900[3];
    uint8_t calib_stat;
  };

  RangeEntry ranges_[kRangeSlots]{};
  std::size_t range_head_ = 0;  // next slot written
  std::size_t range_count_ = 0;
  ImuEntry imus_[kImuSlots]{};
  std::size_t imu_head_ = 0;
  std::size_t imu_count_ = 0;
};

}  // namespace icgt::core
