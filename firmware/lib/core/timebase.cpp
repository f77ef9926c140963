#include "core/timebase.hpp"

#include "protocol/messages.hpp"

namespace icgt::core {

static_assert(static_cast<uint8_t>(ClockSource::free_running) ==
              static_cast<uint8_t>(proto::ClockSource::free_running));
static_assert(static_cast<uint8_t>(ClockSource::rtc) == static_cast<uint8_t>(proto::ClockSource::rtc));
static_assert(static_cast<uint8_t>(ClockSource::rtc_and_pps) ==
              static_cast<uint8_t>(proto::ClockSource::rtc_and_pps));
static_assert(static_cast<uint8_t>(ClockSource::host_set) == static_cast<uint8_t>(proto::ClockSource::host_set));
static_assert(static_cast<uint8_t>(SetTimeResult::ok) == static_cast<uint8_t>(proto::ErrorCode::ok));
static_assert(static_cast<uint8_t>(SetTimeResult::invalid_time) ==
              static_cast<uint8_t>(proto::ErrorCode::invalid_time));
static_assert(static_cast<uint8_t>(SetTimeResult::internal) == static_cast<uint8_t>(proto::ErrorCode::internal));
static_assert(std::atomic<bool>::is_always_lock_free, "shared with the PPS interrupt");

namespace {
constexpr int64_t kUsPerS = 1'000'000;

// Floor division for the seconds of a UTC time (always >= 2020 here, but be exact anyway).
constexpr int64_t floor_div_s(int64_t utc_us) {
  const int64_t q = utc_us / kUsPerS;
  return (utc_us % kUsPerS < 0) ? q - 1 : q;
}
}  // namespace

Timebase::Timebase(hal::Rtc& rtc, hal::EdgeInput* pps) : rtc_(rtc), pps_(pps) {}

Timebase::~Timebase() { stop_pps(); }

void Timebase::begin(uint64_t now_us) {
  int64_t utc_s = 0;
  // An RTC that reads before 2020 was reset to its default date: as good as never set.
  if (rtc_.get_utc_s(utc_s) && utc_s >= kMinValidUtcUs / kUsPerS) {
    rtc_set_ = true;
    watching_ = true;
    rtc_stalled_ = false;
    watch_last_s_ = utc_s;
    watch_last_read_t_us_ = now_us;
    watch_start_t_us_ = now_us;
  } else {
    rtc_set_ = false;
    watching_ = false;
  }
}

void Timebase::poll(uint64_t now_us) {
  if (watching_) step_rollover_watch(now_us);
  if (rtc_phase_pending_) step_rtc_phase(now_us);

  // Lock is lost when the next edge is overdue. Only judged with the queue empty: a queued
  // edge that the loop has not popped yet is not a missing one.
  if (pps_locked_ && pps_queue_.empty() && now_us > pps_last_t_us_ + kPpsPeriodUs + kPpsToleranceUs) {
    pps_locked_ = false;
    pps_run_ = 0;
  }
}

void Timebase::step_rollover_watch(uint64_t now_us) {
  int64_t utc_s = 0;
  if (!rtc_.get_utc_s(utc_s)) {
    // A failed read says nothing about when the rollover happened; the window stays open
    // from the last good read.
    ++rtc_errors_;
  } else if (utc_s != watch_last_s_) {
    rtc_utc_us_at_boot_ = utc_s * kUsPerS - static_cast<int64_t>(now_us);
    rtc_anchored_ = true;
    watching_ = false;
    if (!host_set_) {
      utc_us_at_boot_ = rtc_utc_us_at_boot_;
      anchor_uncertainty_us_ = now_us - watch_last_read_t_us_;
      anchored_ = true;
    }
    return;
  } else {
    watch_last_read_t_us_ = now_us;
  }
  if (now_us - watch_start_t_us_ > kRolloverWaitUs) {
    watching_ = false;
    rtc_stalled_ = true;
  }
}

void Timebase::step_rtc_phase(uint64_t now_us) {
  const int64_t utc_now_us = utc_us_at_boot_ + static_cast<int64_t>(now_us);
  const int64_t utc_now_s = floor_div_s(utc_now_us);
  if (utc_now_s < rtc_phase_target_s_) return;
  // Written just after a boundary, so the restarted prescaler is behind by one loop period
  // at most. A late loop only makes this write as good as the first one, never worse.
  if (!rtc_.set_utc_s(utc_now_s)) ++rtc_errors_;
  rtc_phase_pending_ = false;
}

SetTimeResult Timebase::set_time(int64_t utc_us, uint64_t t_us) {
  if (utc_us < kMinValidUtcUs) return SetTimeResult::invalid_time;
  const int64_t utc_s = floor_div_s(utc_us);
  if (!rtc_.set_utc_s(utc_s)) {
    ++rtc_errors_;
    return SetTimeResult::internal;
  }
  rtc_set_ = true;
  rtc_stalled_ = false;
  watching_ = false;  // a rollover after our own write would measure our write, not UTC
  host_set_ = true;
  anchored_ = true;
  utc_us_at_boot_ = utc_us - static_cast<int64_t>(t_us);
  anchor_uncertainty_us_ = 0;
  rtc_phase_pending_ = true;
  rtc_phase_target_s_ = utc_s + 1;
  return SetTimeResult::ok;
}

ClockSource Timebase::clock_source() const {
  if (!anchored_) return ClockSource::free_running;
  if (host_set_) return ClockSource::host_set;
  return pps_locked_ ? ClockSource::rtc_and_pps : ClockSource::rtc;
}

bool Timebase::to_utc_us(uint64_t t_us, int64_t& utc_us) const {
  if (!anchored_) return false;
  utc_us = utc_us_at_boot_ + static_cast<int64_t>(t_us);
  return true;
}

bool Timebase::start_pps(bool rising) {
  if (pps_ == nullptr) return false;
  set_pps_rising(rising);
  if (pps_attached_) return true;
  pps_attached_ = pps_->attach(&Timebase::on_pps_edge, this);
  return pps_attached_;
}

void Timebase::stop_pps() {
  if (pps_ == nullptr || !pps_attached_) return;
  pps_->detach();
  pps_attached_ = false;
  pps_locked_ = false;
  pps_run_ = 0;
}

void Timebase::on_pps_edge(void* ctx, bool level_high, uint64_t t_us) {
  auto* self = static_cast<Timebase*>(ctx);
  if (level_high != self->pps_rising_.load(std::memory_order_relaxed)) return;  // the trailing edge
  const uint32_t count = self->pps_count_.load(std::memory_order_relaxed) + 1;
  self->pps_count_.store(count, std::memory_order_relaxed);
  PpsEdge edge;
  edge.t_us = t_us;
  edge.count = count;
  (void)self->pps_queue_.push(edge);  // counted by the queue when full; the count shows the gap
}

bool Timebase::pop_pps(PpsEdge& out) {
  if (!pps_queue_.pop(out)) return false;
  // Edges are in time order; a dropped edge shows up as a ~2 s gap and restarts the run.
  if (pps_have_last_ && out.t_us > pps_last_t_us_) {
    const uint64_t dt_us = out.t_us - pps_last_t_us_;
    const bool on_time = dt_us + kPpsToleranceUs >= kPpsPeriodUs && dt_us <= kPpsPeriodUs + kPpsToleranceUs;
    pps_run_ = on_time ? pps_run_ + 1 : 1;
  } else {
    pps_run_ = 1;
  }
  if (pps_run_ > kPpsLockEdges) pps_run_ = kPpsLockEdges;  // saturate: only ">= 3" matters
  pps_have_last_ = true;
  pps_last_t_us_ = out.t_us;
  pps_locked_ = pps_run_ >= kPpsLockEdges;
  return true;
}

}  // namespace icgt::core
