#include "core/trigger.hpp"

#include "protocol/messages.hpp"

namespace icgt::core {

// The application forwards these enums to and from the wire unchanged.
static_assert(static_cast<uint8_t>(CaptureMode::interval) == static_cast<uint8_t>(proto::CaptureMode::interval));
static_assert(static_cast<uint8_t>(CaptureMode::focus_burst) ==
              static_cast<uint8_t>(proto::CaptureMode::focus_burst));
static_assert(static_cast<uint8_t>(CaptureMode::single) == static_cast<uint8_t>(proto::CaptureMode::single));
static_assert(static_cast<uint8_t>(CaptureMode::count) == static_cast<uint8_t>(proto::CaptureMode::count));
static_assert(static_cast<uint8_t>(CaptureState::idle) == static_cast<uint8_t>(proto::CaptureState::idle));
static_assert(static_cast<uint8_t>(CaptureState::capturing) ==
              static_cast<uint8_t>(proto::CaptureState::capturing));
static_assert(static_cast<uint8_t>(CaptureState::finished) == static_cast<uint8_t>(proto::CaptureState::finished));
static_assert(static_cast<uint8_t>(TriggerResult::ok) == static_cast<uint8_t>(proto::ErrorCode::ok));
static_assert(static_cast<uint8_t>(TriggerResult::out_of_range) ==
              static_cast<uint8_t>(proto::ErrorCode::out_of_range));
static_assert(static_cast<uint8_t>(TriggerResult::busy_capturing) ==
              static_cast<uint8_t>(proto::ErrorCode::busy_capturing));
static_assert(static_cast<uint8_t>(TriggerResult::not_capturing) ==
              static_cast<uint8_t>(proto::ErrorCode::not_capturing));
static_assert(std::atomic<CaptureState>::is_always_lock_free, "state is shared with the alarm interrupt");

namespace {
constexpr uint8_t kFocusCycleFlag = static_cast<uint8_t>(proto::ExposureFlags::focus_cycle);
}  // namespace

Trigger::Trigger(hal::Alarm& alarm, const hal::Clock& clock, hal::DigitalOut& shutter, hal::DigitalOut& focus,
                 LinePolarity polarity)
    : alarm_(alarm), clock_(clock), shutter_(shutter), focus_(focus), polarity_(polarity) {
  write_shutter(false);
  write_focus(false);
  alarm_.set_handler(&Trigger::alarm_thunk, this);
}

Trigger::~Trigger() {
  // The alarm may outlive us (simulator teardown order): it must never call a dead object.
  alarm_.cancel();
  alarm_.set_handler(nullptr, nullptr);
}

proto::Limit Trigger::check(const CaptureParams& p) {
  bool uses_interval = true;
  switch (p.mode) {
    case CaptureMode::interval:
      break;
    case CaptureMode::focus_burst:
      if (p.burst_us < p.interval_us) return proto::Limit::burst;
      break;
    case CaptureMode::single:
      uses_interval = false;
      break;
    case CaptureMode::count:
      if (p.count < 1) return proto::Limit::count;
      break;
    default:
      return proto::Limit::capture_mode;  // an unknown value cast from the wire
  }
  if (p.shutter_pulse_us < kMinPulseUs || p.shutter_pulse_us > kMaxPulseUs) return proto::Limit::shutter_pulse;
  if (uses_interval) {
    if (p.interval_us < kMinIntervalUs || p.interval_us > kMaxIntervalUs) return proto::Limit::interval;
    // The line must go inactive between shots or the camera sees one long press.
    if (p.shutter_pulse_us >= p.interval_us) return proto::Limit::pulse_vs_interval;
  }
  return proto::Limit::none;
}

TriggerResult Trigger::validate(const CaptureParams& p) {
  return check(p) == proto::Limit::none ? TriggerResult::ok : TriggerResult::out_of_range;
}

TriggerResult Trigger::start(const CaptureParams& params, uint64_t now_us) {
  if (state() == CaptureState::capturing) return TriggerResult::busy_capturing;
  const TriggerResult valid = validate(params);
  if (valid != TriggerResult::ok) return valid;

  // The alarm is disarmed here (idle or finished), so the handler cannot observe a half-built
  // schedule.
  params_ = params;
  uses_focus_ = params.focus_lead_us > 0;
  repeat_cycles_ = params.mode == CaptureMode::focus_burst;
  switch (params.mode) {
    case CaptureMode::interval:
      shots_per_cycle_ = 0;
      break;
    case CaptureMode::focus_burst:
      // Shots at 0, interval, ... strictly inside [0, burst): ceil(burst / interval).
      shots_per_cycle_ = (uint64_t{params.burst_us} + params.interval_us - 1) / params.interval_us;
      break;
    case CaptureMode::single:
      shots_per_cycle_ = 1;
      break;
    case CaptureMode::count:
      shots_per_cycle_ = params.count;
      break;
  }
  cycle_period_us_ = uint64_t{params.focus_lead_us} + shots_per_cycle_ * params.interval_us;
  capture_start_t_us_ = now_us;
  cycle_index_ = 0;
  shot_in_cycle_ = 0;
  cycle_first_shot_t_us_ = now_us + params.focus_lead_us;
  next_shot_t_us_ = cycle_first_shot_t_us_;
  shot_pending_ = true;
  pulse_active_ = false;
  focus_on_pending_ = uses_focus_;
  focus_on_t_us_ = now_us;

  state_.store(CaptureState::capturing, std::memory_order_release);
  // Even the first focus edge is written by the handler, so every line change has the same
  // (interrupt) timing path.
  alarm_.arm_at(now_us);
  return TriggerResult::ok;
}

TriggerResult Trigger::stop() {
  if (state() != CaptureState::capturing) return TriggerResult::not_capturing;
  // Cancel first: once it returns the handler cannot run again, so the line writes below
  // cannot be undone by a late interrupt.
  alarm_.cancel();
  write_shutter(false);
  write_focus(false);
  shot_pending_ = false;
  pulse_active_ = false;
  focus_on_pending_ = false;
  state_.store(CaptureState::idle, std::memory_order_release);
  return TriggerResult::ok;
}

TriggerResult Trigger::set_polarity(LinePolarity polarity) {
  if (state() == CaptureState::capturing) return TriggerResult::busy_capturing;
  polarity_ = polarity;
  write_shutter(false);
  write_focus(false);
  return TriggerResult::ok;
}

void Trigger::alarm_thunk(void* ctx, uint64_t now_us) { static_cast<Trigger*>(ctx)->on_alarm(now_us); }

Trigger::Event Trigger::next_event(uint64_t& t_us) const {
  // On equal times: end a pulse before anything else, raise focus before shooting.
  Event best = Event::none;
  t_us = 0;
  auto consider = [&](bool pending, uint64_t t, Event e) {
    if (pending && (best == Event::none || t < t_us)) {
      best = e;
      t_us = t;
    }
  };
  consider(pulse_active_, pulse_end_t_us_, Event::pulse_end);
  consider(focus_on_pending_, focus_on_t_us_, Event::focus_on);
  consider(shot_pending_, next_shot_t_us_, Event::shot);
  return best;
}

void Trigger::on_alarm(uint64_t now_us) {
  if (state_.load(std::memory_order_acquire) != CaptureState::capturing) return;
  // Runs every event that is due, then re-arms for the next one. Terminates: each step
  // consumes an event and only schedules events later than the one consumed.
  for (;;) {
    uint64_t t_us = 0;
    const Event event = next_event(t_us);
    switch (event) {
      case Event::none:
        return;  // finished (end_pulse() already published the state)
      case Event::pulse_end:
        if (t_us > now_us) break;
        end_pulse();
        continue;
      case Event::focus_on:
        if (t_us > now_us) break;
        write_focus(true);
        focus_on_pending_ = false;
        continue;
      case Event::shot:
        if (t_us > now_us) break;
        fire_shot();
        continue;
    }
    alarm_.arm_at(t_us);
    return;
  }
}

void Trigger::fire_shot() {
  write_shutter(true);
  // Read right after the write: this is the time the host pairs with feedback and pose.
  const uint64_t fired_t_us = clock_.now_us();
  const uint32_t index = last_image_index_.load(std::memory_order_relaxed) + 1;
  last_image_index_.store(index, std::memory_order_relaxed);
  triggers_fired_.store(triggers_fired_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);

  TriggerRecord record;
  record.image_index = index;
  record.camera_id = params_.camera_id;
  record.flags = params_.mode == CaptureMode::focus_burst ? kFocusCycleFlag : 0;
  record.trigger_t_us = fired_t_us;
  (void)records_.push(record);  // a full queue is counted by the queue; the shot still fires

  // The pulse is measured from the real assertion, so a late interrupt never shortens it.
  pulse_active_ = true;
  pulse_end_t_us_ = fired_t_us + params_.shutter_pulse_us;

  ++shot_in_cycle_;
  if (shots_per_cycle_ != 0 && shot_in_cycle_ >= shots_per_cycle_) {
    shot_pending_ = false;  // end_pulse() closes the cycle
  } else {
    next_shot_t_us_ = cycle_first_shot_t_us_ + shot_in_cycle_ * params_.interval_us;
  }
}

void Trigger::end_pulse() {
  write_shutter(false);
  pulse_active_ = false;
  if (shot_pending_) return;  // more shots in this cycle

  // Last pulse of the cycle: release the half-press.
  if (uses_focus_) write_focus(false);
  if (repeat_cycles_) {
    ++cycle_index_;
    const uint64_t cycle_start_t_us = capture_start_t_us_ + cycle_index_ * cycle_period_us_;
    focus_on_pending_ = uses_focus_;
    focus_on_t_us_ = cycle_start_t_us;
    cycle_first_shot_t_us_ = cycle_start_t_us + params_.focus_lead_us;
    next_shot_t_us_ = cycle_first_shot_t_us_;
    shot_in_cycle_ = 0;
    shot_pending_ = true;
    return;
  }
  state_.store(CaptureState::finished, std::memory_order_release);
}

}  // namespace icgt::core
