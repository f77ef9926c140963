#include "board/sim_gpio.hpp"

namespace icgt::sim {

void RecordingDigitalOut::write(bool high) {
  const uint64_t t_us = clock_.now_us();
  const bool changed = high != level_;
  level_ = high;
  if (recording_) writes_.push_back({t_us, high});
  if (changed && listener_) listener_(high, t_us);
}

std::vector<LineSample> RecordingDigitalOut::edges() const {
  std::vector<LineSample> out;
  bool prev = recorded_from_level_;
  for (const LineSample& s : writes_) {
    if (s.level != prev) out.push_back(s);
    prev = s.level;
  }
  return out;
}

bool SimEdgeInput::attach(Handler handler, void* ctx) {
  if (!wired_ || handler == nullptr) return false;
  handler_ = handler;
  ctx_ = ctx;
  return true;
}

void SimEdgeInput::detach() {
  handler_ = nullptr;
  ctx_ = nullptr;
}

void SimEdgeInput::fire(bool level, uint64_t t_us) {
  level_ = level;
  if (handler_ == nullptr) return;
  ++delivered_;
  handler_(ctx_, level, t_us);
}

void SimEdgeInput::pulse(bool active_level, uint64_t start_t_us, uint64_t end_t_us) {
  fire(active_level, start_t_us);
  fire(!active_level, end_t_us);
}

bool VirtualAlarm::fire_if_due(const VirtualClock& clock) {
  if (!armed_ || deadline_us_ > clock.now_us()) return false;
  // Disarm before calling: the handler may re-arm (one-shot semantics).
  armed_ = false;
  ++fired_;
  if (handler_ != nullptr) handler_(ctx_, clock.now_us());
  return true;
}

std::size_t VirtualAlarm::run_until(VirtualClock& clock, uint64_t t_end_us, std::size_t max_fires) {
  VirtualAlarm* self = this;
  return run_alarms_until(clock, t_end_us, &self, 1, max_fires);
}

std::size_t run_alarms_until(VirtualClock& clock, uint64_t t_end_us, VirtualAlarm* const* alarms,
                             std::size_t alarm_count, std::size_t max_fires) {
  std::size_t fired = 0;
  while (fired < max_fires) {
    VirtualAlarm* next = nullptr;
    for (std::size_t i = 0; i < alarm_count; ++i) {
      VirtualAlarm* a = alarms[i];
      if (a->armed() && a->deadline_us() <= t_end_us && (next == nullptr || a->deadline_us() < next->deadline_us())) {
        next = a;
      }
    }
    if (next == nullptr) break;
    clock.set_us(next->deadline_us());  // never backwards: a past deadline fires "now"
    if (next->fire_if_due(clock)) ++fired;
  }
  clock.set_us(t_end_us);
  return fired;
}

}  // namespace icgt::sim
