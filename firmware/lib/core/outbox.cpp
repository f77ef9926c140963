#include "core/outbox.hpp"

namespace icgt::core {

static_assert(proto::Range::kMaxBodyBytes <= kSampleBodyBytes, "RANGE must fit the sample slots");
static_assert(proto::Status::kMaxBodyBytes <= kEventBodyBytes, "STATUS must fit the event slots");
static_assert(proto::Hello::kMaxBodyBytes <= kEventBodyBytes, "HELLO must fit the event slots");

void Outbox::pump(hal::ByteStream& link, uint64_t now_us) {
  for (;;) {
    if (wire_sent_ == wire_len_) {
      wire_len_ = wire_sent_ = 0;
      if (!build_next(now_us)) return;
    }
    const std::size_t room = link.writable();
    if (room == 0) return;
    const std::size_t want = wire_len_ - wire_sent_;
    const std::size_t n = link.write(wire_ + wire_sent_, want < room ? want : room);
    wire_sent_ += n;
    if (n == 0) return;
  }
}

void Outbox::link_lost() {
  wire_len_ = wire_sent_ = 0;
  resync_ = true;
}

bool Outbox::build_next(uint64_t now_us) {
  if (build_from(events_, now_us)) return true;
  // Samples alternate so a 500 Hz range stream cannot starve the IMU (or the reverse).
  if (prefer_range_) {
    if (build_from(range_, now_us) || build_from(imu_, now_us)) {
      prefer_range_ = false;
      return true;
    }
  } else if (build_from(imu_, now_us) || build_from(range_, now_us)) {
    prefer_range_ = true;
    return true;
  }
  return build_from(log_, now_us);
}

template <std::size_t N, std::size_t C>
bool Outbox::build_from(SpscQueue<QueuedBody<N>, C>& q, uint64_t now_us) {
  QueuedBody<N> slot;
  if (!q.pop(slot)) return false;
  if (slot.type == static_cast<uint8_t>(proto::MsgId::TIME_SYNC_REPLY)) {
    // The transmit time is taken as late as the device can: when the frame is built.
    proto::TimeSyncReply reply;
    if (reply.decode(slot.body, slot.len)) {
      reply.device_tx_t_us = now_us;
      slot.len = static_cast<uint8_t>(reply.encode(slot.body, sizeof slot.body));
    }
  }
  std::size_t offset = 0;
  if (resync_) {
    wire_[0] = 0;
    offset = 1;
    resync_ = false;
  }
  proto::FrameHeader h;
  h.type = slot.type;
  h.seq = seq_;
  const std::size_t n = proto::encode_frame(h, slot.body, slot.len, wire_ + offset, sizeof wire_ - offset);
  if (n == 0) return false;  // cannot happen for a body that fit its slot; nothing is sent
  ++seq_;
  ++sent_;
  wire_len_ = offset + n;
  wire_sent_ = 0;
  return true;
}

OutboxCounters Outbox::counters() const {
  OutboxCounters c;
  c.messages_sent = sent_;
  c.dropped_imu = imu_.dropped();
  c.dropped_range = range_.dropped();
  c.dropped_log = log_.dropped();
  c.dropped_event = events_.dropped();
  return c;
}

}  // namespace icgt::core
