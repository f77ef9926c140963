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
  if (last_trigger_t_us_ != 0) trigger_period_us_ = t_us - last_trigger_t_us_;
  last_trigger_t_us_ = t_us;
  on_trigger_pulse(t_us);
  if (held_manual_t_us_ != 0 && trigger_period_us_ != 0) {
    // After the trigger's own exposure (numbered first, as the camera takes it first).
    held_manual_t_us_ = 0;
    expose(0, t_us + (cfg_.latency_us + trigger_period_us_) / 2, true, 0);
  }
}

void CameraModel::on_trigger_pulse(uint64_t t_us) {
  const bool forced = std::find(forced_misses_.begin(), forced_misses_.end(), triggers_seen_) != forced_misses_.end();
  if (forced || (cfg_.miss_every != 0 && triggers_seen_ % cfg_.miss_every == 0)) {
    ignore(triggers_seen_, t_us, IgnoredReason::forced);
    return;
  }
  // The body's top frame rate, judged on the exposure start the press asks for (without jitter).
  const uint64_t nominal_start_t_us = t_us + cfg_.latency_us;
  if (cfg_.min_frame_period_us != 0 && exposed_ &&
      nominal_start_t_us < last_nominal_start_t_us_ + cfg_.min_frame_period_us) {
    ignore(triggers_seen_, t_us, IgnoredReason::too_soon);
    return;
  }
  if (cfg_.buffer_shots != 0 && buffered_at(t_us) >= cfg_.buffer_shots) {
    ignore(triggers_seen_, t_us, IgnoredReason::buffer_full);
    return;
  }
  int64_t jitter = 0;
  if (cfg_.latency_jitter_us > 0) {
    std::uniform_int_distribution<int64_t> d(-static_cast<int64_t>(cfg_.latency_jitter_us),
                                             static_cast<int64_t>(cfg_.latency_jitter_us));
    jitter = d(rng_);
  }
  const int64_t latency = std::max<int64_t>(0, static_cast<int64_t>(cfg_.latency_us) + jitter);
  exposed_ = true;
  last_nominal_start_t_us_ = nominal_start_t_us;
  expose(t_us, t_us + static_cast<uint64_t>(latency), false, triggers_seen_);
}

void CameraModel::manual_shot(uint64_t t_us) { expose(0, t_us, true, 0); }

void CameraModel::manual_shot_between_triggers(uint64_t t_us) {
  if (steady_trigger(t_us)) {
    held_manual_t_us_ = t_us;
  } else {
    manual_shot(t_us);
  }
}

void CameraModel::release_held_manual_shot(uint64_t t_us) {
  if (held_manual_t_us_ != 0 && !steady_trigger(t_us)) {
    held_manual_t_us_ = 0;
    manual_shot(t_us);
  }
}

const char* ignored_reason_name(IgnoredReason r) {
  switch (r) {
    case IgnoredReason::forced: return "forced";
    case IgnoredReason::buffer_full: return "buffer_full";
    case IgnoredReason::too_soon: return "too_soon";
  }
  return "unknown";
}

void CameraModel::ignore(uint32_t trigger_index, uint64_t t_us, IgnoredReason reason) {
  ++triggers_missed_;
  ignored_.push_back({trigger_index, t_us, reason});
}

void CameraModel::drain(uint64_t t_us) {
  // One frame at a time goes to the card, each taking write_us; writing starts as soon as a
  // frame is buffered.
  while (buffered_ > 0 && write_done_t_us_ <= t_us) {
    --buffered_;
    if (buffered_ > 0) write_done_t_us_ += cfg_.write_us;
  }
}

uint32_t CameraModel::buffered_at(uint64_t t_us) {
  drain(t_us);
  return buffered_;
}

void CameraModel::expose(uint64_t trigger_t_us, uint64_t start_t_us, bool manual, uint32_t trigger_index) {
  TrueExposure e;
  e.frame_number = ++frames_;
  e.trigger_index = trigger_index;
  e.trigger_t_us = trigger_t_us;
  e.start_t_us = start_t_us;
  e.end_t_us = start_t_us + cfg_.exposure_us;
  e.manual = manual;
  exposures_.push_back(e);
  if (cfg_.buffer_shots != 0) {
    drain(start_t_us);
    if (buffered_ == 0) write_done_t_us_ = e.end_t_us + cfg_.write_us;
    ++buffered_;
  }
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
