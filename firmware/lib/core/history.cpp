#include "core/history.hpp"

#include <cstring>

namespace icgt::core {
namespace {

// a - b as a signed distance on the 2^32 sequence circle.
int32_t seq_diff(uint32_t a, uint32_t b) { return static_cast<int32_t>(a - b); }

}  // namespace

template <std::size_t Body, std::size_t Slots>
void FrameRing<Body, Slots>::put(uint32_t seq, uint8_t type, const uint8_t* body, std::size_t len) {
  Slot& s = slots_[head_];
  s.seq = seq;
  s.type = type;
  s.len = static_cast<uint8_t>(len > Body ? Body : len);
  std::memcpy(s.body, body, s.len);
  head_ = (head_ + 1) % Slots;
  if (count_ < Slots) ++count_;
}

template <std::size_t Body, std::size_t Slots>
auto FrameRing<Body, Slots>::first_in(uint32_t from, uint32_t end) const -> const Slot* {
  std::size_t lo = 0;
  std::size_t hi = count_;
  while (lo < hi) {  // the first kept frame at or after `from`
    const std::size_t mid = lo + (hi - lo) / 2;
    if (seq_diff(at(mid).seq, from) < 0) {
      lo = mid + 1;
    } else {
      hi = mid;
    }
  }
  if (lo == count_) return nullptr;
  const Slot& s = at(lo);
  return seq_diff(s.seq, end) < 0 ? &s : nullptr;
}

void History::record(uint32_t seq, uint8_t type, const uint8_t* body, std::size_t len) {
  const FrameKind k = kind_of_type(type);
  const std::size_t i = seq & (kSizes.kind_entries - 1);
  const unsigned shift = static_cast<unsigned>((i & 3u) * 2u);
  kinds_[i / 4] = static_cast<uint8_t>((kinds_[i / 4] & ~(3u << shift)) | (static_cast<unsigned>(k) << shift));
  switch (static_cast<proto::MsgId>(type)) {
    case proto::MsgId::EXPOSURE:
    case proto::MsgId::PPS: events_.put(seq, type, body, len); break;
    case proto::MsgId::IMU: imu_.put(seq, type, body, len); break;
    case proto::MsgId::RANGE: range_.put(seq, type, body, len); break;
    default: break;
  }
  next_seq_ = seq + 1;
  ++recorded_;
}

bool History::next_kept(uint32_t from, uint32_t end, HistoryEntry& out) const {
  const auto* e = events_.first_in(from, end);
  const auto* m = imu_.first_in(from, end);
  const auto* r = range_.first_in(from, end);
  uint32_t best_seq = 0;
  const uint8_t* body = nullptr;
  uint8_t type = 0;
  uint8_t len = 0;
  auto consider = [&](const auto* s) {
    if (s != nullptr && (body == nullptr || seq_diff(s->seq, best_seq) < 0)) {
      best_seq = s->seq;
      body = s->body;
      type = s->type;
      len = s->len;
    }
  };
  consider(e);
  consider(m);
  consider(r);
  if (body == nullptr) return false;
  out.seq = best_seq;
  out.type = type;
  out.len = len;
  out.body = body;
  return true;
}

uint32_t History::first_known_seq() const {
  const uint64_t known = recorded_ < kSizes.kind_entries ? recorded_ : kSizes.kind_entries;
  return next_seq_ - static_cast<uint32_t>(known);
}

bool History::kind(uint32_t seq, FrameKind& out) const {
  const int32_t back = seq_diff(next_seq_, seq);  // 1 = the newest frame
  const uint64_t known = recorded_ < kSizes.kind_entries ? recorded_ : kSizes.kind_entries;
  if (back < 1 || static_cast<uint64_t>(back) > known) return false;
  const std::size_t i = seq & (kSizes.kind_entries - 1);
  out = static_cast<FrameKind>((kinds_[i / 4] >> ((i & 3u) * 2u)) & 3u);
  return true;
}

}  // namespace icgt::core
