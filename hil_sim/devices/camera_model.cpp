#include "devices/camera_model.hpp"

#include <algorithm>
#include <cstdint>
#include <limits>

namespace icgt::sim {

CameraModel::CameraModel(const CameraModelConfig& config) : cfg_(config), rng_(config.seed) {}

void CameraModel::on_shutter_line(bool level, uint64_t t_us) {
  const bool active = level == cfg_.shutter_active_high;
  const bool rising = active && !shutter_active_;
  shutter_active_ = active;
  if (!rising) return;
  ++triggers_seen_;
  const bool forced = std::find(forced_misses_.begin(), forced_misses_.end(), triggers_seen_) != forced_misses_.end();
  if (forced || (cfg_.miss_every != 0 && triggers_seen_ % cfg_.miss_every == 0)) {
    ++triggers_missed_;
    return;
  }
  int64_t jitter = 0;
  if (cfg_.latency_jitter_us > 0) {
    std::uniform_int_distribution<int64_t> d(-static_cast<int64_t>(cfg_.latency_jitter_us),
                                             static_cast<int64_t>(cfg_.latency_jitter_us));
    jitter = d(rng_);
  }
  const int64_t latency = std::max<int64_t>(0, static_cast<int64_t>(cfg_.latency_us) + jitter);
  expose(t_us, t_us + static_cast<uint64_t>(latency), false, triggers_seen_);
}

void CameraModel::manual_shot(uint64_t t_us) { expose(0, t_us, true, 0); }

void CameraModel::expose(uint64_t trigger_t_us, uint64_t start_t_us, bool manual, uint32_t trigger_index) {
  TrueExposure e;
  e.frame_number = ++frames_;
  e.trigger_index = trigger_index;
  e.trigger_t_us = trigger_t_us;
  e.start_t_us = start_t_us;
  e.end_t_us = start_t_us + cfg_.exposure_us;
  e.manual = manual;
  exposures_.push_back(e);
  const bool active = cfg_.feedback_active_high;
  pending_.push_back({e.start_t_us, active});
  pending_.push_back({e.end_t_us, !active});
  std::stable_sort(pending_.begin(), pending_.end(), [](const Edge& a, const Edge& b) { return a.t_us < b.t_us; });
}

uint64_t CameraModel::deliver_until(uint64_t t_us) {
  std::size_t n = 0;
  while (n < pending_.size() && pending_[n].t_us <= t_us) {
    if (feedback_) feedback_(pending_[n].level, pending_[n].t_us);
    ++n;
  }
  pending_.erase(pending_.begin(), pending_.begin() + static_cast<std::ptrdiff_t>(n));
  return next_edge_t_us();
}

uint64_t CameraModel::next_edge_t_us() const {
  return pending_.empty() ? std::numeric_limits<uint64_t>::max() : pending_.front().t_us;
}

}  // namespace icgt::sim
