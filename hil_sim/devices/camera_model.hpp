// A camera on the trigger cable and the hot shoe: it answers a shutter pulse with an
// exposure after a latency, signals the exposure on its flash-sync contact (the feedback
// line), can miss shots and can be fired by hand (a shot with no trigger).
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
  // Missing the trigger with this 1-based index.
  void miss_trigger(uint32_t trigger_index) { forced_misses_.push_back(trigger_index); }

  // Delivers every feedback edge due at or before t_us. Returns the next pending edge time
  // (UINT64_MAX if none), so a scheduler can wake exactly then.
  uint64_t deliver_until(uint64_t t_us);
  [[nodiscard]] uint64_t next_edge_t_us() const;

  [[nodiscard]] const std::vector<TrueExposure>& exposures() const { return exposures_; }
  [[nodiscard]] uint32_t triggers_seen() const { return triggers_seen_; }
  [[nodiscard]] uint32_t triggers_missed() const { return triggers_missed_; }

 private:
  struct Edge {
    uint64_t t_us;
    bool level;
  };
  void expose(uint64_t trigger_t_us, uint64_t start_t_us, bool manual, uint32_t trigger_index);

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
};

}  // namespace icgt::sim
