// The device's memory of what it sent, for RESEND (SPEC.md §3, "Retransmission").
//
// Every frame the outbox builds, whether the link took it or the link was down and it went
// nowhere, is recorded here under its sequence number: its kind (2 bits per sequence number,
// in a ring of kKindEntries) and, for the frames worth sending again, its body. Events
// (EXPOSURE, PPS) have their own ring, kept far longer than the samples (IMU and RANGE rings):
// one event ring slot per exposure or PPS edge, so its reach in time does not depend on the
// sensor rates. Everything else (STATUS, HELLO, DEVICE_STATE, ACK, TIME_SYNC_REPLY, LOG,
// RESEND_LOST) is cumulative or stale once late and is never kept, only its kind is.
//
// No heap: every ring is a fixed array inside the object, sized per board below
// (firmware/cross/build.sh checks the budgets and prints the figures).
#pragma once

#include <cstddef>
#include <cstdint>

#include "messages.hpp"

namespace icgt::core {

enum class FrameKind : uint8_t { other = 0, exposure = 1, pps = 2, sample = 3 };

[[nodiscard]] constexpr FrameKind kind_of_type(uint8_t type) {
  switch (static_cast<proto::MsgId>(type)) {
    case proto::MsgId::EXPOSURE: return FrameKind::exposure;
    case proto::MsgId::PPS: return FrameKind::pps;
    case proto::MsgId::IMU:
    case proto::MsgId::RANGE: return FrameKind::sample;
    default: return FrameKind::other;
  }
}

// Ring sizes per board. Exposures at 5 fps with PPS at 1 Hz are 6 events per second.
struct HistorySizes {
  std::size_t event_slots;
  std::size_t imu_slots;
  std::size_t range_slots;
  std::size_t kind_entries;  // power of two
};

// An event slot is 64 bytes since protocol version 2 (40 before): the EXPOSURE body grew from 34 to 56
// bytes with its sensor snapshot (snapshot.hpp), which is what lets an exposure outlive its samples.
// Teensy 4.1 (i.MX RT1062, 512 KiB tightly coupled data RAM of 1 MiB): 4096 events = 11.4 min of
// 5 fps exposures with PPS (at least 10 minutes required), 512 IMU samples (5.1 s at 100 Hz),
// 1024 ranges (5.1 s at 200 Hz), kinds of the last 2^18 frames (14 min at 310 frames/s).
inline constexpr HistorySizes kTeensy41History{4096, 512, 1024, std::size_t{1} << 18};
// Teensy 3.6 (MK66FX1M0, 256 KiB RAM in all): what fits beside the core, the USB stack and the
// stack: 2048 events = 5.7 min of 5 fps exposures with PPS (3072 = 8.5 min with the 40-byte slots
// of version 1; each exposure now brings its range and attitude back with it), 128 IMU samples
// (1.3 s), 256 ranges (1.3 s), kinds of the last 2^17 frames (7 min at 310 frames/s).
inline constexpr HistorySizes kTeensy36History{2048, 128, 256, std::size_t{1} << 17};

#if defined(ICGT_BOARD_TEENSY36) || defined(ARDUINO_TEENSY36) || defined(__MK66FX1M0__)
inline constexpr HistorySizes kHistorySizes = kTeensy36History;
#else
// Teensy 4.1, and the simulator and host tests, which run the 4.1's figures.
inline constexpr HistorySizes kHistorySizes = kTeensy41History;
#endif

// The 10 minutes of exposures required of the Teensy 4.1 (issue 12), checked where it is stated.
static_assert(kTeensy41History.event_slots >= 10 * 60 * (5 + 1), "Teensy 4.1: 10 min of 5 fps exposures + PPS");

inline constexpr std::size_t kEventHistoryBody = proto::Exposure::kMaxBodyBytes;
static_assert(proto::Pps::kMaxBodyBytes <= kEventHistoryBody, "PPS must fit the event history slots");
static_assert(sizeof(uint32_t) + 2 + kEventHistoryBody <= 64, "an event slot (seq, type, len, body) stays 64 bytes");

// Frames of one kind in sequence order; the oldest is overwritten when full.
template <std::size_t Body, std::size_t Slots>
class FrameRing {
 public:
  struct Slot {
    uint32_t seq;
    uint8_t type;
    uint8_t len;
    uint8_t body[Body];
  };

  void put(uint32_t seq, uint8_t type, const uint8_t* body, std::size_t len);
  // The oldest kept frame with seq in [from, end) (sequence arithmetic mod 2^32), or null.
  [[nodiscard]] const Slot* first_in(uint32_t from, uint32_t end) const;
  [[nodiscard]] std::size_t size() const { return count_; }
  [[nodiscard]] static constexpr std::size_t capacity() { return Slots; }
  [[nodiscard]] static constexpr std::size_t bytes() { return sizeof(Slot) * Slots; }

 private:
  [[nodiscard]] const Slot& at(std::size_t logical) const {  // 0 = oldest
    return slots_[(head_ + Slots - count_ + logical) % Slots];
  }
  Slot slots_[Slots]{};
  std::size_t head_ = 0;  // next slot written
  std::size_t count_ = 0;
};

struct HistoryEntry {
  uint32_t seq = 0;
  uint8_t type = 0;
  uint8_t len = 0;
  const uint8_t* body = nullptr;
};

class History {
 public:
  static constexpr HistorySizes kSizes = kHistorySizes;
  static_assert((kSizes.kind_entries & (kSizes.kind_entries - 1)) == 0, "kind_entries must be a power of two");

  // Every frame, in sequence order (seq = the previous one + 1).
  void record(uint32_t seq, uint8_t type, const uint8_t* body, std::size_t len);
  // The oldest kept frame with seq in [from, end); false if none.
  [[nodiscard]] bool next_kept(uint32_t from, uint32_t end, HistoryEntry& out) const;
  // What `seq` carried; nullopt-like: false when it is too old, or not sent yet.
  [[nodiscard]] bool kind(uint32_t seq, FrameKind& out) const;
  // The oldest sequence number whose kind is known (next_seq() when nothing was recorded).
  [[nodiscard]] uint32_t first_known_seq() const;
  [[nodiscard]] uint32_t next_seq() const { return next_seq_; }

  [[nodiscard]] static constexpr std::size_t bytes() {
    return decltype(events_)::bytes() + decltype(imu_)::bytes() + decltype(range_)::bytes() + kSizes.kind_entries / 4;
  }

 private:
  FrameRing<kEventHistoryBody, kSizes.event_slots> events_;
  FrameRing<proto::Imu::kMaxBodyBytes, kSizes.imu_slots> imu_;
  FrameRing<proto::Range::kMaxBodyBytes, kSizes.range_slots> range_;
  uint8_t kinds_[kSizes.kind_entries / 4]{};  // 2 bits per sequence number
  uint32_t next_seq_ = 0;
  uint64_t recorded_ = 0;
};

}  // namespace icgt::core
