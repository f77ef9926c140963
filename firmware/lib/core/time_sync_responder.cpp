#include "core/time_sync_responder.hpp"

namespace icgt::core {

uint32_t TimeSyncResponder::next_random() {
  // xorshift32 (Marsaglia): no library RNG on the device, and statistical quality is not needed.
  rng_ ^= rng_ << 13;
  rng_ ^= rng_ >> 17;
  rng_ ^= rng_ << 5;
  return rng_;
}

void TimeSyncResponder::hold(const proto::TimeSyncReply& reply, uint64_t rx_t_us, Outbox& outbox) {
  for (Slot& s : slots_) {
    if (s.used) continue;
    s.used = true;
    s.due_t_us = rx_t_us + next_random() % (kDitherUs + 1);
    s.reply = reply;
    return;
  }
  (void)outbox.push(reply);  // every slot held: answer now (a full event queue counts the drop)
}

void TimeSyncResponder::release_due(uint64_t now_us, Outbox& outbox) {
  for (Slot& s : slots_) {
    if (!s.used || s.due_t_us > now_us) continue;
    s.used = false;
    (void)outbox.push(s.reply);
  }
}

void TimeSyncResponder::clear() {
  for (Slot& s : slots_) s.used = false;
}

std::size_t TimeSyncResponder::held() const {
  std::size_t n = 0;
  for (const Slot& s : slots_) n += s.used ? 1 : 0;
  return n;
}

}  // namespace icgt::core
