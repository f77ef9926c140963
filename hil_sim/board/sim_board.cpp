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
  bus_.set_timing(cfg_.i2c_timing);
  if (cfg_.i2c_takes_time) bus_.set_time_passer([this](uint64_t t_us) { pass_time(t_us); });
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

uint64_t SimBoard::next_irq_t_us() const {
  constexpr uint64_t kNever = std::numeric_limits<uint64_t>::max();
  const uint64_t t_alarm = alarm_.armed() ? alarm_.deadline_us() : kNever;
  const uint64_t t_feedback = camera_.next_edge_t_us();
  const uint64_t t_pps = pps_edges_.empty() ? kNever : pps_edges_.front().t_us;
  return std::min({t_alarm, t_feedback, t_pps});
}

void SimBoard::fire_next_irq(uint64_t t_us) {
  // The alarm first at equal times (the trigger's interrupt is the most urgent on the board).
  if (alarm_.armed() && alarm_.deadline_us() <= t_us) {
    (void)alarm_.fire_if_due(clock_);
  } else if (camera_.next_edge_t_us() <= t_us) {
    (void)camera_.deliver_until(t_us);
  } else if (!pps_edges_.empty() && pps_edges_.front().t_us <= t_us) {
    pps_.fire(pps_edges_.front().level, pps_edges_.front().t_us);
    pps_edges_.erase(pps_edges_.begin());
  }
}

void SimBoard::pass_time(uint64_t t_us) {
  for (uint64_t t = next_irq_t_us(); t <= t_us; t = next_irq_t_us()) {
    clock_.set_us(t);
    fire_next_irq(t);
  }
  clock_.set_us(t_us);
}

void SimBoard::run_until(uint64_t t_us) {
  while (clock_.now_us() <= t_us) {
    // The next thing that happens: an interrupt (alarm, feedback or PPS edge) or a main-loop
    // iteration. Interrupts come first at equal times, as on the chip.
    const uint64_t t_irq = next_irq_t_us();
    const uint64_t t_next = std::min(t_irq, next_loop_t_us_);
    if (t_next > t_us) {
      clock_.set_us(t_us);
      return;
    }
    clock_.set_us(t_next);
    if (t_irq <= t_next) {
      fire_next_irq(t_next);
    } else {
      const uint64_t start = clock_.now_us();
      app_->poll();  // I2C inside moves the clock on (pass_time)
      ++loop_iterations_;
      loop_busy_us_ += clock_.now_us() - start;
      next_loop_t_us_ = std::max(next_loop_t_us_ + cfg_.loop_period_us, clock_.now_us() + 1);
    }
  }
}

}  // namespace icgt::sim
