// A camera on the trigger cable and the hot shoe: it answers a shutter pulse with an
// exposure after a latency, signals the exposure on its flash-sync contact (the feedback
// line), can miss shots and can be fired by hand (a shot with no trigger).
//
// Fast bursts behave as real bodies do: the shutter lag may be longer than the interval (the
// exposure starts after the next trigger fired); a press sooner than min_frame_period_us after
// the last exposure started is ignored (the body's top frame rate); every shot goes into a
// buffer of buffer_shots frames that the card empties at one frame per write_us, and a press
// while the buffer is full is ignored until a frame has been written. Typical numbers (Sony
// Alpha 9, Sony's ILCE-9 specifications): 20 fps at most (electronic shutter), a buffer of
// about 362 JPEG or 241 compressed RAW frames; shutter lag of mirrorless bodies ~25-50 ms
// (Wikipedia, "Shutter lag"). Every ignored press is recorded with its reason.
#pragma once

#include <cstdint>
#include <functional>
#include <random>
#include <vector>

namespace icgt::sim {

struct CameraModelConfig {
  uint32_t latency_us = 48'000;       // shutter line asserted -> exposure starts (shutter lag)
  uint32_t latency_jitter_us = 2'000; // uniform +- around latency_us
  uint32_t exposure_us = 1'000;       // 1/1000 s
  bool feedback_active_high = false;  // hot-shoe contacts pull the line low
  bool shutter_active_high = true;    // polarity the camera expects on its trigger input
  uint32_t miss_every = 0;            // every Nth trigger is ignored (0 = never)
  uint32_t min_frame_period_us = 0;   // top frame rate: 50'000 = 20 fps (0 = no limit)
  uint32_t buffer_shots = 0;          // frames the buffer holds (0 = unlimited)
  uint32_t write_us = 0;              // card write time per frame (buffer drain)
  uint64_t seed = 7;
};

// One exposure as it really happened (ground truth for tests and the simulator's truth file).
struct TrueExposure {
  uint32_t frame_number = 0;    // the camera's own count (DSC00001 ...), manual shots included
  uint32_t trigger_index = 0;   // 1-based count of trigger pulses seen; 0 for a manual shot
  uint64_t trigger_t_us = 0;    // device clock
  uint64_t start_t_us = 0;
  uint64_t end_t_us = 0;
  bool manual = false;
};

enum class IgnoredReason : uint8_t { forced, buffer_full, too_soon };

// A trigger pulse the camera did not answer.
struct IgnoredTrigger {
  uint32_t trigger_index = 0;
  uint64_t trigger_t_us = 0;
  IgnoredReason reason = IgnoredReason::forced;
};

[[nodiscard]] const char* ignored_reason_name(IgnoredReason r);

class CameraModel {
 public:
  using EdgeSink = std::function<void(bool level, uint64_t t_us)>;

  explicit CameraModel(const CameraModelConfig& config = {});

  // Wire the flash-sync contact to a line (called with every edge, at its time, in order).
  void connect_feedback(EdgeSink sink) { feedback_ = std::move(sink); }

  // The trigger cable: called on every shutter-line write.
  void on_shutter_line(bool level, uint64_t t_us);
  // A hand-pressed shot at t_us (no trigger).
  void manual_shot(uint64_t t_us);
  // A hand-pressed shot pressed at t_us and taken half-way between two triggered exposures: at the
  // next trigger pulse, (shutter lag + trigger period) / 2 after it, so that it is always as far
  // from the triggered exposures on both sides whatever the phase of the trigger (the phase of a
  // capture started over a real link varies from run to run). Without a steady trigger (none yet,
  // or none for two periods) it is taken at once: see release_held_manual_shot.
  void manual_shot_between_triggers(uint64_t t_us);
  // A shot held by manual_shot_between_triggers is taken now (at t_us) if no trigger came for two
  // periods (capture stopped). Call it as time advances.
  void release_held_manual_shot(uint64_t t_us);
  // Missing the trigger with this 1-based index.
  void miss_trigger(uint32_t trigger_index) { forced_misses_.push_back(trigger_index); }

  // Delivers every feedback edge due at or before t_us. Returns the next pending edge time
  // (UINT64_MAX if none), so a scheduler can wake exactly then.
  uint64_t deliver_until(uint64_t t_us);
  [[nodiscard]] uint64_t next_edge_t_us() const;

  [[nodiscard]] const std::vector<TrueExposure>& exposures() const { return exposures_; }
  [[nodiscard]] uint32_t triggers_seen() const { return triggers_seen_; }
  [[nodiscard]] uint32_t triggers_missed() const { return triggers_missed_; }
  [[nodiscard]] const std::vector<IgnoredTrigger>& ignored() const { return ignored_; }
  // Frames in the buffer at t_us (not yet written to the card).
  [[nodiscard]] uint32_t buffered_at(uint64_t t_us);

 private:
  struct Edge {
    uint64_t t_us;
    bool level;
  };
  void on_trigger_pulse(uint64_t t_us);  // the camera's answer to one trigger pulse (or none)
  void expose(uint64_t trigger_t_us, uint64_t start_t_us, bool manual, uint32_t trigger_index);
  void ignore(uint32_t trigger_index, uint64_t t_us, IgnoredReason reason);
  void drain(uint64_t t_us);

  CameraModelConfig cfg_;
  std::mt19937_64 rng_;
  EdgeSink feedback_;
  bool shutter_active_ = false;
  uint32_t triggers_seen_ = 0;
  uint32_t triggers_missed_ = 0;
  uint32_t frames_ = 0;
  std::vector<uint32_t> forced_misses_;
  std::vector<Edge> pending_;  // sorted by time
  std::vector<TrueExposure> exposures_;
  std::vector<IgnoredTrigger> ignored_;
  bool exposed_ = false;  // a triggered exposure happened (the frame-rate limit applies)
  uint64_t last_nominal_start_t_us_ = 0;
  uint32_t buffered_ = 0;
  uint64_t write_done_t_us_ = 0;  // the frame being written is on the card then
  uint64_t last_trigger_t_us_ = 0;  // the last trigger pulse's rising edge (0: none yet)
  uint64_t trigger_period_us_ = 0;  // between the last two trigger pulses (0: fewer than two)
  uint64_t held_manual_t_us_ = 0;   // when a shot held for the next trigger was pressed (0: none)
  [[nodiscard]] bool steady_trigger(uint64_t t_us) const {
    return trigger_period_us_ != 0 && t_us <= last_trigger_t_us_ + 2 * trigger_period_us_;
  }
};

}  // namespace icgt::sim
