// A fixed-capacity, lock-free, single-producer / single-consumer ring.
//
// The hand-off between an interrupt handler (the producer: trigger alarm, feedback edge,
// PPS edge) and the main loop (the consumer). The interrupt records a small struct and
// returns; everything slow happens in the loop.
//
// Contract:
//  - Exactly one context calls push() (and only it), exactly one other context calls
//    pop()/peek()/empty()/size(). Nothing else touches the ring.
//  - push() never blocks and never overwrites: when the ring is full the new element is
//    refused (push returns false) and counted in dropped(). Keeping the oldest data is
//    deliberate: a consumer that fell behind must still see a gap-free prefix, and the
//    drop count tells the host how much is missing.
//  - pushed() + dropped() is every push attempt; pushed() - popped() is the fill level.
//
// Indices are free-running 32-bit counters (head - tail is the fill level even across
// wrap-around, because Capacity divides 2^32). Only plain 32-bit atomic loads and stores
// are used (single LDR/STR plus barriers on Cortex-M; no LDREX/STREX, no libatomic). The
// lock-free assertion below holds on ARMv7-M (Teensy 3.x M4, 4.x M7, MPS2 M3/M4).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <type_traits>

namespace icgt::core {

template <typename T, std::size_t Capacity>
class SpscQueue {
  static_assert(Capacity >= 2 && (Capacity & (Capacity - 1)) == 0,
                "Capacity must be a power of two so free-running 32-bit indices wrap cleanly");
  static_assert(Capacity <= (std::size_t{1} << 31), "Capacity must leave head - tail unambiguous");
  static_assert(std::is_trivially_copyable_v<T>, "elements are copied in interrupt context");
  static_assert(std::atomic<uint32_t>::is_always_lock_free, "the ring relies on lock-free 32-bit atomics");

 public:
  SpscQueue() = default;
  SpscQueue(const SpscQueue&) = delete;
  SpscQueue& operator=(const SpscQueue&) = delete;

  [[nodiscard]] static constexpr std::size_t capacity() { return Capacity; }

  // Producer side. Returns false (and counts a drop) when full.
  [[nodiscard]] bool push(const T& value) {
    const uint32_t head = head_.load(std::memory_order_relaxed);  // only we write head
    const uint32_t tail = tail_.load(std::memory_order_acquire);  // slot reuse needs the consumer's read done
    if (head - tail >= Capacity) {
      dropped_.store(dropped_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
      return false;
    }
    slots_[head & kMask] = value;
    head_.store(head + 1, std::memory_order_release);  // publishes the slot contents
    return true;
  }

  // Consumer side. Returns false when empty.
  [[nodiscard]] bool pop(T& out) {
    const uint32_t tail = tail_.load(std::memory_order_relaxed);  // only we write tail
    const uint32_t head = head_.load(std::memory_order_acquire);
    if (head == tail) return false;
    out = slots_[tail & kMask];
    tail_.store(tail + 1, std::memory_order_release);  // hands the slot back to the producer
    return true;
  }

  // Consumer side: copies the oldest element without removing it.
  [[nodiscard]] bool peek(T& out) const {
    const uint32_t tail = tail_.load(std::memory_order_relaxed);
    const uint32_t head = head_.load(std::memory_order_acquire);
    if (head == tail) return false;
    out = slots_[tail & kMask];
    return true;
  }

  // Consumer side (the producer may add more at any moment, never remove).
  [[nodiscard]] bool empty() const {
    return head_.load(std::memory_order_acquire) == tail_.load(std::memory_order_relaxed);
  }
  [[nodiscard]] std::size_t size() const {
    return head_.load(std::memory_order_acquire) - tail_.load(std::memory_order_relaxed);
  }

  // Counters, readable from either side (modulo 2^32).
  [[nodiscard]] uint32_t pushed() const { return head_.load(std::memory_order_relaxed); }
  [[nodiscard]] uint32_t popped() const { return tail_.load(std::memory_order_relaxed); }
  [[nodiscard]] uint32_t dropped() const { return dropped_.load(std::memory_order_relaxed); }

 private:
  static constexpr uint32_t kMask = static_cast<uint32_t>(Capacity - 1);

  T slots_[Capacity]{};
  std::atomic<uint32_t> head_{0};     // written by the producer only
  std::atomic<uint32_t> tail_{0};     // written by the consumer only
  std::atomic<uint32_t> dropped_{0};  // written by the producer only
};

}  // namespace icgt::core
