// Holds each TIME_SYNC reply for a random 0..kDitherUs before queueing it (SPEC.md §8).
//
// Why: a USB host polls the device on its frame grid (1 ms full speed, 125 us high speed),
// and a request reaches the device at one phase of that grid. A reply sent at once always
// leaves at the same phase, so it waits nearly a whole frame for the next poll and never
// reaches its path's floor, while requests do: the two-way clock estimate is then biased by
// half that difference (~half a frame). Sent after a uniformly random hold, some replies are
// written just before a poll, and both directions reach their floors. The reply's
// device_tx_t_us is still the time its frame is built, so the hold itself costs no accuracy.
// No heap: a fixed handful of slots; when they are full a reply goes out at once.
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/outbox.hpp"
#include "messages.hpp"

namespace icgt::core {

class TimeSyncResponder {
 public:
  static constexpr uint32_t kDitherUs = 1000;  // one full-speed frame, eight high-speed microframes
  static constexpr std::size_t kSlots = 4;     // hosts send a few per second at most

  // A request received at rx_t_us: hold its reply (or queue it at once if every slot is taken).
  void hold(const proto::TimeSyncReply& reply, uint64_t rx_t_us, Outbox& outbox);
  // Queue every reply whose hold has ended by now_us.
  void release_due(uint64_t now_us, Outbox& outbox);
  // The link went away: the host that asked is gone, and a new one matches replies to its own requests.
  void clear();

  [[nodiscard]] std::size_t held() const;

 private:
  [[nodiscard]] uint32_t next_random();

  struct Slot {
    bool used = false;
    uint64_t due_t_us = 0;
    proto::TimeSyncReply reply;
  };
  Slot slots_[kSlots]{};
  uint32_t rng_ = 0x9E3779B9u;  // xorshift32 state; any non-zero seed (the phase only needs to vary)
};

}  // namespace icgt::core
