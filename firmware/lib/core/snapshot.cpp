#include "core/snapshot.hpp"

#include <cmath>

#include "protocol/messages.hpp"

namespace icgt::core {

static_assert(snapshot_flags::range_valid == proto::SnapshotFlags::range_valid);
static_assert(snapshot_flags::range_interpolated == proto::SnapshotFlags::range_interpolated);
static_assert(snapshot_flags::imu_valid == proto::SnapshotFlags::imu_valid);
static_assert(snapshot_flags::imu_interpolated == proto::SnapshotFlags::imu_interpolated);

namespace {

constexpr float kQ14 = 16384.0F;
constexpr float kRad900 = 900.0F;

uint16_t age_us(uint64_t a, uint64_t b) {
  const uint64_t d = a > b ? a - b : b - a;
  return d >= SensorSnapshot::kAgeSaturated ? SensorSnapshot::kAgeSaturated : static_cast<uint16_t>(d);
}

int16_t to_i16(float v) {
  if (!(v == v)) return 0;  // NaN: the driver never delivers one; the wire must not carry garbage
  const float r = std::round(v);
  if (r >= 32767.0F) return 32767;
  if (r <= -32768.0F) return -32768;
  return static_cast<int16_t>(r);
}

// In a ring of Slots entries with `count` kept and `head` the next written, logical 0 = oldest.
template <class Entry, std::size_t Slots>
const Entry& entry(const Entry (&ring)[Slots], std::size_t head, std::size_t count, std::size_t logical) {
  return ring[(head + Slots - count + logical) % Slots];
}

// The newest entry at or before mid (a) and the oldest at or after it (b), as logical indices; -1 if none.
// Entries are in time order (both drivers stamp monotonically).
template <class Entry, std::size_t Slots>
void bracket(const Entry (&ring)[Slots], std::size_t head, std::size_t count, uint64_t mid_us, long& a, long& b) {
  a = -1;
  b = -1;
  for (std::size_t i = count; i-- > 0;) {
    const uint64_t t = entry(ring, head, count, i).t_us;
    if (t >= mid_us) b = static_cast<long>(i);
    if (t <= mid_us) {
      a = static_cast<long>(i);
      break;
    }
  }
}

// Whether a and b both exist and lie within the bracket window of mid (then interpolate).
bool both_near(uint64_t ta, uint64_t tb, uint64_t mid_us) {
  return mid_us - ta <= SensorSnapshot::kBracketUs && tb - mid_us <= SensorSnapshot::kBracketUs;
}

}  // namespace

void SensorSnapshot::add_range(const RangeSample& s) {
  if (!s.valid) return;
  RangeEntry& e = ranges_[range_head_];
  e.t_us = s.acq_start_t_us;
  const uint32_t mm = static_cast<uint32_t>(s.distance_cm) * 10u;
  e.range_mm = mm > 0xFFFFu ? 0xFFFFu : static_cast<uint16_t>(mm);
  range_head_ = (range_head_ + 1) % kRangeSlots;
  if (range_count_ < kRangeSlots) ++range_count_;
}

void SensorSnapshot::add_imu(const ImuSample& s) {
  ImuEntry& e = imus_[imu_head_];
  e.t_us = s.read_start_t_us + (s.read_end_t_us - s.read_start_t_us) / 2;
  e.quat_q14[0] = to_i16(s.quat_w * kQ14);
  e.quat_q14[1] = to_i16(s.quat_x * kQ14);
  e.quat_q14[2] = to_i16(s.quat_y * kQ14);
  e.quat_q14[3] = to_i16(s.quat_z * kQ14);
  e.gyro_rad900[0] = to_i16(s.gyro_x_rad_s * kRad900);
  e.gyro_rad900[1] = to_i16(s.gyro_y_rad_s * kRad900);
  e.gyro_rad900[2] = to_i16(s.gyro_z_rad_s * kRad900);
  e.calib_stat = s.calib_stat;
  imu_head_ = (imu_head_ + 1) % kImuSlots;
  if (imu_count_ < kImuSlots) ++imu_count_;
}

void SensorSnapshot::clear() {
  range_head_ = range_count_ = 0;
  imu_head_ = imu_count_ = 0;
}

bool SensorSnapshot::settled(uint64_t mid_us, uint64_t now_us, bool range_on, bool imu_on) const {
  if (now_us >= mid_us + kBracketUs) return true;
  const bool range_in =
      !range_on || (range_count_ > 0 && entry(ranges_, range_head_, range_count_, range_count_ - 1).t_us >= mid_us);
  const bool imu_in =
      !imu_on || (imu_count_ > 0 && entry(imus_, imu_head_, imu_count_, imu_count_ - 1).t_us >= mid_us);
  return range_in && imu_in;
}

Snapshot SensorSnapshot::at(uint64_t mid_us) const {
  Snapshot out;
  long a = -1;
  long b = -1;
  bracket(ranges_, range_head_, range_count_, mid_us, a, b);
  if (a >= 0 || b >= 0) {
    out.flags |= snapshot_flags::range_valid;
    const RangeEntry* ea = a >= 0 ? &entry(ranges_, range_head_, range_count_, static_cast<std::size_t>(a)) : nullptr;
    const RangeEntry* eb = b >= 0 ? &entry(ranges_, range_head_, range_count_, static_cast<std::size_t>(b)) : nullptr;
    if (ea != nullptr && eb != nullptr && eb->t_us != ea->t_us && both_near(ea->t_us, eb->t_us, mid_us)) {
      out.flags |= snapshot_flags::range_interpolated;
      // Rounded to the nearest mm: num / den with num of either sign.
      const int64_t num =
          (static_cast<int64_t>(eb->range_mm) - ea->range_mm) * static_cast<int64_t>(mid_us - ea->t_us);
      const int64_t den = static_cast<int64_t>(eb->t_us - ea->t_us);
      out.range_mm = static_cast<uint16_t>(ea->range_mm + (2 * num + (num >= 0 ? den : -den)) / (2 * den));
      const uint16_t age_a = age_us(mid_us, ea->t_us);
      const uint16_t age_b = age_us(eb->t_us, mid_us);
      out.range_age_us = age_a < age_b ? age_a : age_b;
    } else {
      const RangeEntry* n = ea;
      if (n == nullptr || (eb != nullptr && eb->t_us - mid_us < mid_us - ea->t_us)) n = eb;
      out.range_mm = n->range_mm;
      out.range_age_us = age_us(mid_us, n->t_us);
    }
  }

  bracket(imus_, imu_head_, imu_count_, mid_us, a, b);
  if (a >= 0 || b >= 0) {
    out.flags |= snapshot_flags::imu_valid;
    const ImuEntry* ea = a >= 0 ? &entry(imus_, imu_head_, imu_count_, static_cast<std::size_t>(a)) : nullptr;
    const ImuEntry* eb = b >= 0 ? &entry(imus_, imu_head_, imu_count_, static_cast<std::size_t>(b)) : nullptr;
    const ImuEntry* nearest = ea;
    if (nearest == nullptr || (eb != nullptr && eb->t_us - mid_us < mid_us - ea->t_us)) nearest = eb;
    if (ea != nullptr && eb != nullptr && eb->t_us != ea->t_us && both_near(ea->t_us, eb->t_us, mid_us)) {
      out.flags |= snapshot_flags::imu_interpolated;
      const float f = static_cast<float>(mid_us - ea->t_us) / static_cast<float>(eb->t_us - ea->t_us);
      float qa[4];
      float qb[4];
      float dot = 0.0F;
      for (int i = 0; i < 4; ++i) {
        qa[i] = static_cast<float>(ea->quat_q14[i]) / kQ14;
        qb[i] = static_cast<float>(eb->quat_q14[i]) / kQ14;
        dot += qa[i] * qb[i];
      }
      const float sign = dot < 0.0F ? -1.0F : 1.0F;  // q and -q are one rotation: take the short way
      float q[4];
      float norm2 = 0.0F;
      for (int i = 0; i < 4; ++i) {
        q[i] = qa[i] + (sign * qb[i] - qa[i]) * f;
        norm2 += q[i] * q[i];
      }
      const float norm = std::sqrt(norm2);
      for (int i = 0; i < 4; ++i) out.quat_q14[i] = norm > 0.0F ? to_i16(q[i] / norm * kQ14) : 0;
      for (int i = 0; i < 3; ++i) {
        const float wa = ea->gyro_rad900[i];
        const float wb = eb->gyro_rad900[i];
        out.gyro_rad900[i] = to_i16(wa + (wb - wa) * f);
      }
      const uint16_t age_a = age_us(mid_us, ea->t_us);
      const uint16_t age_b = age_us(eb->t_us, mid_us);
      out.imu_age_us = age_a < age_b ? age_a : age_b;
    } else {
      for (int i = 0; i < 4; ++i) out.quat_q14[i] = nearest->quat_q14[i];
      for (int i = 0; i < 3; ++i) out.gyro_rad900[i] = nearest->gyro_rad900[i];
      out.imu_age_us = age_us(mid_us, nearest->t_us);
    }
    out.imu_calib_stat = nearest->calib_stat;
  }
  return out;
}

}  // namespace icgt::core
