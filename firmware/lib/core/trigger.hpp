// The shutter / focus scheduler.
//
// Every line change happens in the hal::Alarm interrupt, never in the main loop, so an I2C
// read or a slow serial write can never delay or stretch a shot. Shots sit on an absolute
// grid (first_shot + k * interval_us) computed from the capture start, so interrupt latency
// on one shot never accumulates into drift.
//
// Each shutter assertion gets the next image index (monotonic since boot, first = 1) and its
// device time, read from the clock in the interrupt right after the line was written. The
// pair goes into records() for the loop (ExposurePairing consumes it).
//
// Modes (values are the protocol's CaptureMode):
//  - interval:    shots at start + focus_lead_us + k * interval_us until stop().
//  - focus_burst: the ICGT paper's cycle. Each cycle: focus asserted for focus_lead_us, then
//                 n = ceil(burst_us / interval_us) shots interval_us apart, focus released
//                 when the last pulse ends; the next cycle starts focus_lead_us + n * interval_us
//                 after the previous one (so focus is released for interval_us - pulse at least).
//                 With 500 ms / 200 ms / 2 s: focus at 0, shots at 0.5 .. 2.3 s, next cycle at 2.5 s.
//  - single:      one shot at start + focus_lead_us, then finished.
//  - count:       `count` shots, then finished.
// If focus_lead_us > 0 the focus (half-press) line is asserted at start (interval, single,
// count: held until the last pulse ends or stop()); if it is 0 the focus line is never touched.
//
// Threading: start(), stop() and set_polarity() run in the loop; the alarm handler preempts
// the loop but never runs concurrently with it (single core). start() publishes the schedule
// before arming the alarm; stop() cancels the alarm before touching the lines.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>

#include "core/limits.hpp"
#include "core/spsc_queue.hpp"
#include "hal/hal.hpp"
#include "protocol/messages.hpp"

namespace icgt::core {

// Values are the protocol's CaptureMode / CaptureState.
enum class CaptureMode : uint8_t { interval = 1, focus_burst = 2, single = 3, count = 4 };
enum class CaptureState : uint8_t { idle = 0, capturing = 1, finished = 2 };

// The subset of the protocol's ErrorCode that the trigger can answer (same values, so the
// application can put it into an ACK unchanged).
enum class TriggerResult : uint8_t { ok = 0, out_of_range = 3, busy_capturing = 4, not_capturing = 5 };

// START_CAPTURE, field for field.
struct CaptureParams {
  CaptureMode mode = CaptureMode::interval;
  uint8_t camera_id = 0;
  uint32_t interval_us = 0;       // interval, focus_burst, count; ignored by single
  uint32_t count = 0;             // count only
  uint32_t focus_lead_us = 0;     // 0 = focus line unused
  uint32_t burst_us = 0;          // focus_burst only
  uint32_t shutter_pulse_us = 0;  // every mode
};

// Active level of each output line (PinPolarity bits focus_active_high / shutter_active_high).
struct LinePolarity {
  bool focus_active_high = true;
  bool shutter_active_high = true;
};

// One shutter assertion, handed from the alarm interrupt to the loop.
struct TriggerRecord {
  uint32_t image_index = 0;
  uint8_t camera_id = 0;
  // ExposureFlags bits known at trigger time: focus_cycle = fired in focus_burst mode (the
  // host groups those shots into bursts by time).
  uint8_t flags = 0;
  uint64_t trigger_t_us = 0;
};

// Sized for the worst case the loop must survive: 20 shots/s (50 ms interval) for 1.6 s of
// stalled loop. A drop here loses an EXPOSURE record; it is counted in records().dropped().
inline constexpr std::size_t kTriggerQueueCapacity = 32;
using TriggerQueue = SpscQueue<TriggerRecord, kTriggerQueueCapacity>;

class Trigger {
 public:
  static constexpr uint32_t kMinIntervalUs = limits::kMinIntervalUs;
  static constexpr uint32_t kMaxIntervalUs = limits::kMaxIntervalUs;
  static constexpr uint32_t kMinPulseUs = limits::kMinPulseUs;
  static constexpr uint32_t kMaxPulseUs = limits::kMaxPulseUs;

  // Takes the alarm's handler. Writes both lines to their inactive level. All references
  // must outlive the Trigger.
  Trigger(hal::Alarm& alarm, const hal::Clock& clock, hal::DigitalOut& shutter, hal::DigitalOut& focus,
          LinePolarity polarity = {});
  ~Trigger();
  Trigger(const Trigger&) = delete;
  Trigger& operator=(const Trigger&) = delete;

  // Checks params against the limits in START_CAPTURE (interval 50 ms .. 3600 s where used,
  // pulse 1 ms .. 1 s and < interval where used, count >= 1 for count, burst >= interval for
  // focus_burst, a known mode). Pure: changes nothing.
  [[nodiscard]] static TriggerResult validate(const CaptureParams& params);
  // The limit params break (proto::Limit::none when valid), for ACK.detail.
  [[nodiscard]] static proto::Limit check(const CaptureParams& params);

  // Starts a capture whose grid begins at now_us (focus asserted at now_us, first shot at
  // now_us + focus_lead_us). Refused (changing nothing) with busy_capturing while a capture
  // runs, out_of_range when validate() fails. Allowed from idle and finished.
  [[nodiscard]] TriggerResult start(const CaptureParams& params, uint64_t now_us);

  // Cancels the schedule and releases both lines at once (a pulse in progress is cut short;
  // its record was already queued). Refused with not_capturing unless capturing.
  [[nodiscard]] TriggerResult stop();

  // Changes the active levels and rewrites both lines inactive. Refused with busy_capturing
  // while capturing (changing polarity mid-pulse would fire or cut a shot).
  [[nodiscard]] TriggerResult set_polarity(LinePolarity polarity);

  [[nodiscard]] CaptureState state() const { return state_.load(std::memory_order_acquire); }
  [[nodiscard]] uint32_t triggers_fired() const { return triggers_fired_.load(std::memory_order_relaxed); }
  // Index of the last shot fired since boot; 0 before the first.
  [[nodiscard]] uint32_t last_image_index() const { return last_image_index_.load(std::memory_order_relaxed); }
  // The parameters of the current or last accepted capture.
  [[nodiscard]] const CaptureParams& params() const { return params_; }
  [[nodiscard]] LinePolarity polarity() const { return polarity_; }
  // The loop's end of the interrupt hand-off.
  [[nodiscard]] TriggerQueue& records() { return records_; }

 private:
  enum class Event : uint8_t { none, pulse_end, focus_on, shot };

  static void alarm_thunk(void* ctx, uint64_t now_us);
  void on_alarm(uint64_t now_us);
  [[nodiscard]] Event next_event(uint64_t& t_us) const;
  void fire_shot();
  void end_pulse();
  void write_shutter(bool active) { shutter_.write(active == polarity_.shutter_active_high); }
  void write_focus(bool active) { focus_.write(active == polarity_.focus_active_high); }

  hal::Alarm& alarm_;
  const hal::Clock& clock_;
  hal::DigitalOut& shutter_;
  hal::DigitalOut& focus_;
  LinePolarity polarity_;
  CaptureParams params_{};

  // The schedule. Written by start()/stop() while the alarm is disarmed, otherwise only by
  // the alarm handler; state_ (release in start, acquire in the handler) orders the two.
  uint64_t capture_start_t_us_ = 0;
  uint64_t cycle_period_us_ = 0;   // focus_burst: focus_lead + n * interval
  uint64_t shots_per_cycle_ = 0;   // 0 = unlimited (interval mode)
  bool repeat_cycles_ = false;     // focus_burst
  bool uses_focus_ = false;
  uint64_t cycle_index_ = 0;
  uint64_t cycle_first_shot_t_us_ = 0;
  uint64_t shot_in_cycle_ = 0;     // shots fired in the current cycle
  bool shot_pending_ = false;
  uint64_t next_shot_t_us_ = 0;
  bool pulse_active_ = false;
  uint64_t pulse_end_t_us_ = 0;
  bool focus_on_pending_ = false;
  uint64_t focus_on_t_us_ = 0;

  std::atomic<CaptureState> state_{CaptureState::idle};
  std::atomic<uint32_t> triggers_fired_{0};    // written by the handler only
  std::atomic<uint32_t> last_image_index_{0};  // written by the handler only
  TriggerQueue records_;
};

}  // namespace icgt::core
