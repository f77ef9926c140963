// The transmit path: fixed-size queues of encoded message bodies, a priority between them,
// and sequence numbers assigned when a frame is built, so the host sees them in order.
//
// Events (EXPOSURE, PPS, ACK, TIME_SYNC_REPLY, HELLO, STATUS) have their own queue and are
// sent before any sample: under link saturation the sample queues fill first and shed new
// samples, each drop counted by cause (SPEC.md §8). No heap: all storage is in the object.
//
// Every frame built is recorded in the history (core/history.hpp) under its sequence number.
// While the link is down frames are still built and recorded, only not written (discard()):
// the host sees their sequence numbers missing when it is back and asks RESEND for them.
// RESEND requests wait in a small queue; their frames are sent after live events and before
// live samples (alternating with them), and each request ends with a RESEND_LOST.
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/history.hpp"
#include "core/spsc_queue.hpp"
#include "frame.hpp"
#include "hal/hal.hpp"

namespace icgt::core {

template <std::size_t MaxBody>
struct QueuedBody {
  uint8_t type = 0;
  uint8_t len = 0;
  uint8_t body[MaxBody]{};
};

// The largest body each queue holds; static_asserts in outbox.cpp keep them honest.
inline constexpr std::size_t kEventBodyBytes = 96;
inline constexpr std::size_t kSampleBodyBytes = proto::Imu::kMaxBodyBytes;
inline constexpr std::size_t kLogBodyBytes = proto::Log::kMaxBodyBytes;

struct OutboxCounters {
  uint32_t messages_sent = 0;
  uint32_t dropped_imu = 0;
  uint32_t dropped_range = 0;
  uint32_t dropped_log = 0;
  uint32_t dropped_event = 0;
  uint32_t resend_requests = 0;
  uint32_t frames_resent = 0;
  uint32_t sent_while_down = 0;  // frames built and recorded while no host listened
};

class Outbox {
 public:
  static constexpr std::size_t kEventCapacity = 64;   // 12 s of 5 fps exposures with a host not reading
  static constexpr std::size_t kImuCapacity = 16;     // 160 ms at 100 Hz
  static constexpr std::size_t kRangeCapacity = 64;   // 128 ms at 500 Hz
  static constexpr std::size_t kLogCapacity = 8;
  static constexpr std::size_t kResendQueue = 8;        // RESEND requests waiting to be answered
  static constexpr uint32_t kResendTallyPerPump = 2048;  // sequence numbers counted per pump, at most

  // Queue a message. Returns false if its queue is full (the drop is counted by cause).
  template <class Msg>
  [[nodiscard]] bool push(const Msg& msg) {
    if constexpr (Msg::kId == proto::MsgId::IMU) {
      return push_to(imu_, msg);
    } else if constexpr (Msg::kId == proto::MsgId::RANGE) {
      return push_to(range_, msg);
    } else if constexpr (Msg::kId == proto::MsgId::LOG) {
      return push_to(log_, msg);
    } else {
      static_assert(Msg::kMaxBodyBytes <= kEventBodyBytes, "event body larger than the event queue's slots");
      return push_to(events_, msg);
    }
  }

  // Writes as much as the link accepts now, frame after frame; never blocks. now_us stamps
  // TIME_SYNC_REPLY.device_tx_t_us when its frame is built.
  void pump(hal::ByteStream& link, uint64_t now_us);

  // The link went away: the frame in progress is abandoned (the host will see its
  // sequence number missing) and the next frame starts with a 0x00 to resynchronise.
  void link_lost();

  // The link is down: build every queued frame and record it in the history without sending
  // it (as if the link had taken it), so no queue fills while no host listens.
  void discard(uint64_t now_us);

  // Queue an answer to RESEND(first_seq, count). False (nothing queued) if the queue is full.
  [[nodiscard]] bool request_resend(uint32_t first_seq, uint32_t count);

  [[nodiscard]] const History& history() const { return history_; }
  [[nodiscard]] OutboxCounters counters() const;
  [[nodiscard]] uint32_t next_seq() const { return seq_; }
  [[nodiscard]] std::size_t queued() const {
    return events_.size() + imu_.size() + range_.size() + log_.size();
  }

 private:
  // 1 after writing the 0x00 a resync owes into wire_[0] (clearing it), else 0: where the frame starts.
  [[nodiscard]] std::size_t take_resync_prefix();
  template <std::size_t N, std::size_t C, class Msg>
  [[nodiscard]] static bool push_to(SpscQueue<QueuedBody<N>, C>& q, const Msg& msg) {
    QueuedBody<N> slot;
    slot.type = static_cast<uint8_t>(Msg::kId);
    const std::size_t n = msg.encode(slot.body, sizeof slot.body);
    if (n == 0 && Msg::kMinBodyBytes != 0) return false;
    slot.len = static_cast<uint8_t>(n);
    return q.push(slot);
  }

  struct ResendJob {
    proto::ResendLost tally;  // first_seq, count and the counts so far
    uint32_t next = 0;        // next sequence number to look at
  };
  enum class ResendStep : uint8_t { idle, built, working };

  [[nodiscard]] bool build_next(uint64_t now_us, bool live);
  [[nodiscard]] ResendStep step_resend();
  void count_missing(ResendJob& job, uint32_t until);
  void record(uint8_t type, const uint8_t* body, std::size_t len);
  template <std::size_t N, std::size_t C>
  [[nodiscard]] bool build_from(SpscQueue<QueuedBody<N>, C>& q, uint64_t now_us);

  SpscQueue<QueuedBody<kEventBodyBytes>, kEventCapacity> events_;
  SpscQueue<QueuedBody<kSampleBodyBytes>, kImuCapacity> imu_;
  SpscQueue<QueuedBody<kSampleBodyBytes>, kRangeCapacity> range_;
  SpscQueue<QueuedBody<kLogBodyBytes>, kLogCapacity> log_;
  bool prefer_range_ = true;  // alternate IMU and RANGE when both wait
  bool prefer_resend_ = true;  // alternate resent frames and live samples when both wait
  History history_;
  ResendJob resends_[kResendQueue]{};
  std::size_t resend_head_ = 0;
  std::size_t resend_count_ = 0;
  uint32_t resend_requests_ = 0;
  uint32_t frames_resent_ = 0;
  uint32_t sent_while_down_ = 0;

  uint8_t wire_[proto::kMaxWireBytes + 1]{};
  std::size_t wire_len_ = 0;
  std::size_t wire_sent_ = 0;
  bool resync_ = true;  // start with 0x00: the host may hold half a frame from before
  uint32_t seq_ = 0;
  uint32_t sent_ = 0;
};

}  // namespace icgt::core
