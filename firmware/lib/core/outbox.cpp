#include "core/outbox.hpp"

namespace icgt::core {

static_assert(proto::Range::kMaxBodyBytes <= kSampleBodyBytes, "RANGE must fit the sample slots");
static_assert(proto::Status::kMaxBodyBytes <= kEventBodyBytes, "STATUS must fit the event slots");
static_assert(proto::Hello::kMaxBodyBytes <= kEventBodyBytes, "HELLO must fit the event slots");
static_assert(proto::DeviceState::kMaxBodyBytes <= kEventBodyBytes, "DEVICE_STATE must fit the event slots");
static_assert(proto::ResendLost::kMaxBodyBytes <= kEventBodyBytes, "RESEND_LOST must fit the event slots");

void Outbox::pump(hal::ByteStream& link, uint64_t now_us) {
  for (;;) {
    if (wire_sent_ == wire_len_) {
      wire_len_ = wire_sent_ = 0;
      if (!build_next(now_us, true)) return;
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
  resend_count_ = 0;  // a host that comes back asks again for what it still misses
}

void Outbox::discard(uint64_t now_us) {
  wire_len_ = wire_sent_ = 0;
  const uint32_t before = seq_;
  while (build_next(now_us, false)) wire_len_ = wire_sent_ = 0;
  sent_while_down_ += seq_ - before;
  resync_ = true;
}

bool Outbox::request_resend(uint32_t first_seq, uint32_t count) {
  if (resend_count_ == kResendQueue) return false;
  ResendJob& job = resends_[(resend_head_ + resend_count_) % kResendQueue];
  job = ResendJob{};
  job.tally.first_seq = first_seq;
  job.tally.count = count;
  job.next = first_seq;
  ++resend_count_;
  ++resend_requests_;
  return true;
}

void Outbox::count_missing(ResendJob& job, uint32_t until) {
  for (uint32_t s = job.next; s != until; ++s) {
    FrameKind k;
    if (!history_.kind(s, k)) {
      ++job.tally.unknown;
      continue;
    }
    switch (k) {
      case FrameKind::exposure: ++job.tally.exposures; break;
      case FrameKind::pps: ++job.tally.pps; break;
      case FrameKind::sample: ++job.tally.samples; break;
      case FrameKind::other: ++job.tally.other; break;
    }
  }
  job.next = until;
}

Outbox::ResendStep Outbox::step_resend() {
  if (resend_count_ == 0) return ResendStep::idle;
  ResendJob& job = resends_[resend_head_];
  const uint32_t end = job.tally.first_seq + job.tally.count;
  const uint32_t left = end - job.next;
  const uint32_t search_end = job.next + (left < kResendTallyPerPump ? left : kResendTallyPerPump);
  HistoryEntry e;
  if (left != 0 && history_.next_kept(job.next, search_end, e)) {
    count_missing(job, e.seq);
    const std::size_t offset = take_resync_prefix();
    proto::FrameHeader h;
    h.type = e.type;
    h.flags = static_cast<uint8_t>(proto::FrameFlags::retransmit);
    h.seq = e.seq;  // the original: retransmits take no new sequence number (SPEC.md §3)
    const std::size_t n = proto::encode_frame(h, e.body, e.len, wire_ + offset, sizeof wire_ - offset);
    job.next = e.seq + 1;
    if (n != 0) {
      ++job.tally.resent;
      ++frames_resent_;
      wire_len_ = offset + n;
      wire_sent_ = 0;
      return ResendStep::built;
    }
    ++job.tally.unknown;  // cannot happen for a body that fit its slot: counted, not hidden
    return ResendStep::working;
  }
  count_missing(job, search_end);
  if (job.next == end) {
    // The end of this answer: what was not sent again, by kind. A full event queue counts the drop
    // and the host asks again when no RESEND_LOST comes.
    (void)push(job.tally);
    resend_head_ = (resend_head_ + 1) % kResendQueue;
    --resend_count_;
  }
  return ResendStep::working;
}

void Outbox::record(uint8_t type, const uint8_t* body, std::size_t len) { history_.record(seq_, type, body, len); }

bool Outbox::build_next(uint64_t now_us, bool live) {
  if (build_from(events_, now_us)) return true;
  const bool samples_wait = !imu_.empty() || !range_.empty();
  if (live && resend_count_ > 0 && (prefer_resend_ || !samples_wait)) {
    if (step_resend() == ResendStep::built) {
      prefer_resend_ = false;
      return true;
    }
    if (build_from(events_, now_us)) return true;  // the RESEND_LOST that ended an answer
  }
  prefer_resend_ = true;
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
  const std::size_t offset = take_resync_prefix();
  proto::FrameHeader h;
  h.type = slot.type;
  h.seq = seq_;
  const std::size_t n = proto::encode_frame(h, slot.body, slot.len, wire_ + offset, sizeof wire_ - offset);
  if (n == 0) return false;  // cannot happen for a body that fit its slot; nothing is sent
  record(slot.type, slot.body, slot.len);
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
  c.resend_requests = resend_requests_;
  c.frames_resent = frames_resent_;
  c.sent_while_down = sent_while_down_;
  return c;
}

std::size_t Outbox::take_resync_prefix() {
  if (!resync_) return 0;
  wire_[0] = 0;  // a delimiter first: ends whatever half frame the host still holds
  resync_ = false;
  return 1;
}

}  // namespace icgt::core
