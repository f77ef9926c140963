#include "board/sim_board.hpp"

#include <algorithm>
#include <limits>

namespace icgt::sim {

SimBoard::SimBoard(const SimBoardConfig& config, hal::ByteStream& link)
    : cfg_(config),
      bus_(clock_),
      bno_(config.bno),
      lidar_(config.lidar),
      camera_(config.camera),
      shutter_(clock_),
      focus_(clock_),
      rtc_(clock_, config.rtc_utc_s_at_boot) {
  if (cfg_.bno_fitted) bus_.attach(0x28, &bno_);
  if (cfg_.lidar_fitted) bus_.attach(LidarLiteModel::kDefaultAddr7, &lidar_);
  feedback_.set_wired(cfg_.feedback_wired);
  shutter_.set_recording(false);  // hours of shots must not grow memory
  focus_.set_recording(false);
  shutter_.set_listener([this](bool level, uint64_t t_us) { camera_.on_shutter_line(level, t_us); });
  camera_.connect_feedback([this](bool level, uint64_t t_us) { feedback_.fire(level, t_us); });
  const core::AppPorts ports{clock_,   link,   bus_,
                             alarm_,   shutter_, focus_,
                             cfg_.feedback_wired ? &feedback_ : nullptr,
                             cfg_.pps_wired ? &pps_ : nullptr,
                             rtc_};
  app_ = std::make_unique<core::App>(ports, cfg_.identity, cfg_.device);
}

void SimBoard::begin() {
  app_->begin();
  next_loop_t_us_ = clock_.now_us();
}

void SimBoard::pps_pulse(uint64_t t_us) {
  if (!cfg_.pps_wired) return;
  pps_edges_.push_back({t_us, true});
  pps_edges_.push_back({t_us + 100'000, false});
  std::stable_sort(pps_edges_.begin(), pps_edges_.end(),
                   [](const LineSample& a, const LineSample& b) { return a.t_us < b.t_us; });
}

void SimBoard::run_until(uint64_t t_us) {
  constexpr uint64_t kNever = std::numeric_limits<uint64_t>::max();
  while (clock_.now_us() <= t_us) {
    // The next thing that happens: an alarm (trigger interrupt), a feedback or PPS edge,
    // or a main-loop iteration. Interrupts come first at equal times, as on the chip.
    const uint64_t t_alarm = alarm_.armed() ? alarm_.deadline_us() : kNever;
    const uint64_t t_feedback = camera_.next_edge_t_us();
    const uint64_t t_pps = pps_edges_.empty() ? kNever : pps_edges_.front().t_us;
    const uint64_t t_irq = std::min({t_alarm, t_feedback, t_pps});
    const uint64_t t_next = std::min(t_irq, next_loop_t_us_);
    if (t_next > t_us) {
      clock_.set_us(t_us);
      return;
    }
    clock_.set_us(t_next);
    if (t_alarm <= t_next) {
      (void)alarm_.fire_if_due(clock_);
    } else if (t_feedback <= t_next) {
      (void)camera_.deliver_until(t_next);
    } else if (t_pps <= t_next) {
      pps_.fire(pps_edges_.front().level, pps_edges_.front().t_us);
      pps_edges_.erase(pps_edges_.begin());
    } else {
      app_->poll();
      next_loop_t_us_ = std::max(next_loop_t_us_ + cfg_.loop_period_us, clock_.now_us() + 1);
    }
  }
}

}  // namespace icgt::sim
