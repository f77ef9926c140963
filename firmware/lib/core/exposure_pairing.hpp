// Pairs camera feedback (hot-shoe / flash-sync edges) with the triggers that caused them.
//
// Producers (interrupts): Trigger pushes a TriggerRecord per shot; on_feedback_edge(), the
// feedback EdgeInput handler, pushes every edge {level, t_us}. Consumer (loop): poll().
//
// Rules, applied in device-time order:
//  - An active edge (level == active level) starts an exposure. It belongs to the oldest
//    pending trigger fired at least min_lag_us (the camera's shortest shutter lag) before it;
//    with none, it is a manual shot: emitted with `unsolicited` and image_index 0. With a
//    shutter lag longer than the interval the edge arrives after the next trigger fired: it
//    still goes to the oldest.
//  - The next inactive edge ends it: emitted with start, end and duration_us = end - start.
//    An inactive edge with no exposure open (line already active at attach, a lost start
//    edge) is ignored and counted in stray_edges().
//  - A trigger with no start edge by trigger_t_us + timeout_us is emitted `feedback_missing`.
//  - A start with no end by start + end_timeout_us, or followed by another start, is
//    emitted `end_missing` (end and duration 0).
//  - With no feedback line configured, every trigger is emitted at once with
//    `no_feedback_line`.
// Mid-exposure is start + duration_us / 2; the host computes it (the device sends raw edges
// so the host can apply a camera-specific model instead).
//
// Pairing is FIFO: it is unambiguous while the window an edge may arrive in,
// [trigger + min_lag_us, trigger + timeout_us], is shorter than the interval: then a trigger
// the camera ignored has timed out before the next one's edge can arrive. With a longer
// window one missed exposure would shift the pairing of following shots until the next gap;
// the application refuses such captures (limits.hpp, App::start_capture).
//
// Deadlines are judged against the next feedback edge or, once the edge queue is empty,
// against now_us, never against the loop's arrival time alone: a late poll() does not turn
// a feedback edge that arrived in time into a timeout.
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/limits.hpp"
#include "core/spsc_queue.hpp"
#include "core/trigger.hpp"
#include "hal/hal.hpp"

namespace icgt::core {

// The protocol's ExposureFlags bits (pinned in exposure_pairing.cpp).
namespace exposure_flags {
inline constexpr uint8_t feedback_missing = 1u << 0;
inline constexpr uint8_t no_feedback_line = 1u << 1;
inline constexpr uint8_t unsolicited = 1u << 2;
inline constexpr uint8_t end_missing = 1u << 3;
inline constexpr uint8_t focus_cycle = 1u << 4;
}  // namespace exposure_flags

// One EXPOSURE message, field for field.
struct Exposure {
  uint32_t image_index = 0;  // 0 = unsolicited
  uint8_t camera_id = 0;
  uint8_t flags = 0;
  uint64_t trigger_t_us = 0;         // 0 if unsolicited
  uint64_t feedback_start_t_us = 0;  // 0 if none
  uint64_t feedback_end_t_us = 0;    // 0 if none
  uint32_t duration_us = 0;          // 0 if unknown
};

struct FeedbackEdge {
  uint64_t t_us = 0;
  bool level_high = false;
};

// Two edges per shot: 16 shots of stalled loop.
inline constexpr std::size_t kFeedbackQueueCapacity = 32;
using FeedbackQueue = SpscQueue<FeedbackEdge, kFeedbackQueueCapacity>;

// The subset of the protocol's ErrorCode that configure() can answer (same values).
enum class FeedbackResult : uint8_t { ok = 0, out_of_range = 3, not_supported = 7 };

struct FeedbackConfig {
  bool enabled = false;      // CONFIGURE.feedback_enabled
  bool active_high = false;  // PinPolarity feedback_active_high; hot shoes usually pull low
  uint32_t timeout_us = 200'000;        // CONFIGURE.feedback_timeout_us (or derived), 1 ms .. 2 s
  uint32_t min_lag_us = 0;              // CONFIGURE.feedback_min_lag_us, 0 .. 1 s, < timeout_us
  uint32_t end_timeout_us = 1'000'000;  // longest exposure expected (not on the wire yet)
};

class ExposurePairing {
 public:
  static constexpr uint32_t kMinTimeoutUs = limits::kMinFeedbackTimeoutUs;
  static constexpr uint32_t kMaxTimeoutUs = limits::kMaxFeedbackTimeoutUs;
  static constexpr uint32_t kMaxMinLagUs = limits::kMaxFeedbackMinLagUs;
  // Triggers waiting for their start edge: 2 s of timeout at 20 shots/s fits.
  static constexpr std::size_t kPendingCapacity = 48;

  // feedback may be null (no line on this board). Everything must outlive the pairing.
  ExposurePairing(TriggerQueue& triggers, hal::EdgeInput* feedback, uint8_t camera_id = 0);
  ~ExposurePairing();
  ExposurePairing(const ExposurePairing&) = delete;
  ExposurePairing& operator=(const ExposurePairing&) = delete;

  // Applies CONFIGURE. Refused (changing nothing) with out_of_range for a timeout outside
  // 1 ms .. 2 s, a min lag above 1 s or not below the timeout, or an end timeout of 0, not_supported when enabled but the line is missing
  // or cannot interrupt. Disabling detaches the line; triggers still waiting are then
  // emitted with no_feedback_line and an open exposure with end_missing.
  [[nodiscard]] FeedbackResult configure(const FeedbackConfig& config);

  // Loop: consumes trigger records and feedback edges, writes up to out_cap finished
  // records to out and returns how many. Nothing is lost when out fills up: call again
  // (a return value equal to out_cap means more may be ready).
  [[nodiscard]] std::size_t poll(uint64_t now_us, Exposure* out, std::size_t out_cap);

  [[nodiscard]] bool feedback_enabled() const { return config_.enabled; }
  [[nodiscard]] const FeedbackConfig& config() const { return config_; }
  [[nodiscard]] uint32_t exposures_confirmed() const { return exposures_confirmed_; }
  [[nodiscard]] uint32_t feedback_missing() const { return feedback_missing_; }
  [[nodiscard]] uint32_t feedback_unsolicited() const { return feedback_unsolicited_; }
  [[nodiscard]] uint32_t end_missing() const { return end_missing_; }
  [[nodiscard]] uint32_t stray_edges() const { return stray_edges_; }
  [[nodiscard]] std::size_t pending_triggers() const { return pending_count_; }
  [[nodiscard]] const FeedbackQueue& edges() const { return edges_; }

  // The feedback EdgeInput handler (interrupt context); public so a board can route it itself.
  static void on_feedback_edge(void* ctx, bool level_high, uint64_t t_us);

 private:
  void pull_triggers();
  [[nodiscard]] const TriggerRecord& pending_front() const { return pending_[pending_head_]; }
  void pending_pop();
  [[nodiscard]] Exposure from_trigger(const TriggerRecord& record, uint8_t flags) const;
  // The open exposure as a record (start filled, end left 0).
  [[nodiscard]] Exposure open_record(uint8_t extra_flags) const;

  TriggerQueue& triggers_;
  hal::EdgeInput* line_;
  uint8_t camera_id_;
  FeedbackConfig config_{};
  bool attached_ = false;

  FeedbackQueue edges_;
  bool have_edge_ = false;  // edge_ popped but not yet consumed (output was full)
  FeedbackEdge edge_{};

  TriggerRecord pending_[kPendingCapacity]{};
  std::size_t pending_head_ = 0;
  std::size_t pending_count_ = 0;

  bool open_ = false;  // a start edge seen, waiting for its end
  bool open_solicited_ = false;
  TriggerRecord open_trigger_{};
  uint64_t open_start_t_us_ = 0;

  uint32_t exposures_confirmed_ = 0;
  uint32_t feedback_missing_ = 0;
  uint32_t feedback_unsolicited_ = 0;
  uint32_t end_missing_ = 0;
  uint32_t stray_edges_ = 0;
};

}  // namespace icgt::core
