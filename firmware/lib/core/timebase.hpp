// The device timebase: anchors the 64-bit microsecond device clock (hal::Clock) to UTC.
//
// The device clock itself is never adjusted (it is monotonic and every record carries it);
// Timebase only keeps the UTC of device time 0 (utc_us_at_boot) and where it came from.
//
// Sources, best last:
//  - free_running: no UTC yet (RTC never set or stopped, no SET_TIME).
//  - rtc:          the battery-backed RTC counts whole seconds only, so the anchor is taken
//                  at a seconds rollover. begin() reads the RTC, then poll() (called every
//                  loop, never blocking) reads it again until the seconds value changes and
//                  records utc_us_at_boot = new_second * 1e6 - t_observed_us.
//                  Resolution: the rollover happened somewhere between the previous RTC read
//                  and t_observed_us, i.e. within one loop period. The anchor is therefore low
//                  by 0 .. anchor_uncertainty_us() (= that read-to-read gap), and UTC derived
//                  from it is early by as much. The host, which sees the same number, can
//                  widen its error bars accordingly.
//  - rtc_and_pps:  rtc, and a GPS PPS is locked (edges 1 s +- 500 us apart, 3 in a row).
//                  PPS does not change the anchor here; the edges go to the host (PPS
//                  messages), which disciplines its mapping with them. PPS without any UTC
//                  anchor still reports free_running (the pulses carry no second labels).
//  - host_set:     SET_TIME gave UTC at a known device time; it overrides the RTC anchor
//                  and also sets the RTC (so the next boot starts from it).
//
// The RTC's seconds phase after SET_TIME: the RTC can only be written in whole seconds, and
// on the Teensy (3.x TSR / 4.x SNVS) a write restarts the sub-second prescaler. So set_time()
// writes floor(utc) at once (so an immediate failure can be reported) and poll() writes
// again at the first second boundary afterwards; the RTC then ticks within one loop period
// of true UTC seconds and the next boot's anchor is as good as the rollover watch allows.
//
// PPS: on_pps_edge() runs in the edge interrupt, counts active edges and queues
// {t_us, count}; the loop drains them with pop_pps() (which also updates the lock).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>

#include "core/spsc_queue.hpp"
#include "hal/hal.hpp"

namespace icgt::core {

// Values are the protocol's ClockSource.
enum class ClockSource : uint8_t { free_running = 0, rtc = 1, rtc_and_pps = 2, host_set = 3 };

// The subset of the protocol's ErrorCode that SET_TIME can answer (same values).
enum class SetTimeResult : uint8_t { ok = 0, invalid_time = 8, internal = 9 };

struct PpsEdge {
  uint64_t t_us = 0;   // device time of the active edge, taken in the interrupt
  uint32_t count = 0;  // active edges seen since boot, this one included (1 = first)
};

// Eight seconds of pulses: the loop is never stalled that long.
inline constexpr std::size_t kPpsQueueCapacity = 8;
using PpsQueue = SpscQueue<PpsEdge, kPpsQueueCapacity>;

class Timebase {
 public:
  static constexpr int64_t kMinValidUtcUs = 1'577'836'800'000'000;  // 2020-01-01T00:00:00Z
  // Give up on the rollover watch if the RTC seconds have not moved by then (oscillator stopped).
  static constexpr uint64_t kRolloverWaitUs = 2'500'000;
  static constexpr uint64_t kPpsPeriodUs = 1'000'000;
  static constexpr uint64_t kPpsToleranceUs = 500;
  static constexpr uint32_t kPpsLockEdges = 3;

  // pps may be null (not wired on this board). Both must outlive the Timebase.
  Timebase(hal::Rtc& rtc, hal::EdgeInput* pps);
  ~Timebase();
  Timebase(const Timebase&) = delete;
  Timebase& operator=(const Timebase&) = delete;

  // Reads the RTC once and starts the rollover watch if it holds a time (>= 2020).
  void begin(uint64_t now_us);
  // Loop step: advances the rollover watch, the RTC phase write, and PPS loss detection.
  // Reads the RTC at most once per call; never waits.
  void poll(uint64_t now_us);

  // SET_TIME: utc_us is UTC at device time t_us (when the frame arrived). Refused, changing
  // nothing, with invalid_time before 2020-01-01 and internal if the RTC write fails.
  [[nodiscard]] SetTimeResult set_time(int64_t utc_us, uint64_t t_us);

  // Attaches the PPS interrupt; rising = the active edge is rising (PinPolarity pps_rising).
  // False if there is no PPS line or it cannot interrupt.
  [[nodiscard]] bool start_pps(bool rising);
  void stop_pps();
  // May be changed while attached (CONFIGURE); takes effect from the next edge.
  void set_pps_rising(bool rising) { pps_rising_.store(rising, std::memory_order_relaxed); }
  // Loop: next queued PPS edge, in order. Updates pps_locked().
  [[nodiscard]] bool pop_pps(PpsEdge& out);

  [[nodiscard]] ClockSource clock_source() const;
  [[nodiscard]] bool anchored() const { return anchored_; }
  // UTC (Unix epoch, us) at device time 0 from the best source; 0 while free_running.
  [[nodiscard]] int64_t utc_us_at_boot() const { return anchored_ ? utc_us_at_boot_ : 0; }
  // The same from the RTC rollover alone (HELLO.rtc_utc_us_at_boot); 0 if never obtained.
  [[nodiscard]] int64_t rtc_utc_us_at_boot() const { return rtc_anchored_ ? rtc_utc_us_at_boot_ : 0; }
  // How much the RTC anchor may be low (see the header comment); 0 for host_set.
  [[nodiscard]] uint64_t anchor_uncertainty_us() const { return anchor_uncertainty_us_; }
  // UTC of a device time; false while free_running.
  [[nodiscard]] bool to_utc_us(uint64_t t_us, int64_t& utc_us) const;

  [[nodiscard]] bool rtc_set() const { return rtc_set_; }          // SensorHealth.rtc_set
  [[nodiscard]] bool rtc_watch_active() const { return watching_; }
  [[nodiscard]] bool rtc_stalled() const { return rtc_stalled_; }  // set but not ticking
  [[nodiscard]] uint32_t rtc_errors() const { return rtc_errors_; }  // failed RTC reads/writes
  [[nodiscard]] bool pps_locked() const { return pps_locked_; }
  [[nodiscard]] uint32_t pps_edges() const { return pps_count_.load(std::memory_order_relaxed); }
  [[nodiscard]] const PpsQueue& pps_queue() const { return pps_queue_; }

  // The PPS EdgeInput handler (interrupt context); public so a board can route it itself.
  static void on_pps_edge(void* ctx, bool level_high, uint64_t t_us);

 private:
  void step_rollover_watch(uint64_t now_us);
  void step_rtc_phase(uint64_t now_us);

  hal::Rtc& rtc_;
  hal::EdgeInput* pps_;

  bool rtc_set_ = false;
  bool watching_ = false;
  bool rtc_stalled_ = false;
  int64_t watch_last_s_ = 0;
  uint64_t watch_last_read_t_us_ = 0;
  uint64_t watch_start_t_us_ = 0;
  bool rtc_anchored_ = false;
  int64_t rtc_utc_us_at_boot_ = 0;

  bool anchored_ = false;
  bool host_set_ = false;
  int64_t utc_us_at_boot_ = 0;
  uint64_t anchor_uncertainty_us_ = 0;

  bool rtc_phase_pending_ = false;
  int64_t rtc_phase_target_s_ = 0;  // first whole second after SET_TIME
  uint32_t rtc_errors_ = 0;

  // PPS: the handler writes pps_count_ and the queue; the rest is loop-only.
  std::atomic<bool> pps_rising_{true};
  std::atomic<uint32_t> pps_count_{0};
  PpsQueue pps_queue_;
  bool pps_attached_ = false;
  bool pps_have_last_ = false;
  uint64_t pps_last_t_us_ = 0;
  uint32_t pps_run_ = 0;  // consecutive edges spaced 1 s +- tolerance
  bool pps_locked_ = false;
};

}  // namespace icgt::core
