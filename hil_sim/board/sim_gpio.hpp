// Simulated GPIO and timer for virtual time: output lines that record every write, edge
// inputs that tests (or the simulated camera / GPS) fire at chosen times, and a one-shot
// alarm whose handler runs at exactly its deadline on a VirtualClock.
//
// Shared by unit tests and the lock-step simulator, so nothing here knows about shutters or
// cameras: a listener hook on outputs lets a device model react to a line.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "board/virtual_clock.hpp"
#include "hal/hal.hpp"

namespace icgt::sim {

struct LineSample {
  uint64_t t_us;
  bool level;
};

// A DigitalOut that timestamps every write with the given clock.
class RecordingDigitalOut final : public hal::DigitalOut {
 public:
  using Listener = std::function<void(bool level, uint64_t t_us)>;

  explicit RecordingDigitalOut(const hal::Clock& clock, bool initial_level = false)
      : clock_(clock), level_(initial_level), recorded_from_level_(initial_level) {}

  void write(bool high) override;

  [[nodiscard]] bool level() const { return level_; }
  // Every write, including writes that do not change the level (a driver that re-writes a
  // line is visible here).
  [[nodiscard]] const std::vector<LineSample>& writes() const { return writes_; }
  // Level changes only, in order (the waveform a scope would show), judged from the level
  // the line had when recording started (construction or the last clear()).
  [[nodiscard]] std::vector<LineSample> edges() const;
  void clear() {
    writes_.clear();
    recorded_from_level_ = level_;
  }
  // Long simulator runs turn recording off; level() and the listener keep working.
  void set_recording(bool on) { recording_ = on; }
  // Called after every write that changes the level (e.g. a simulated camera on the shutter).
  void set_listener(Listener listener) { listener_ = std::move(listener); }

 private:
  const hal::Clock& clock_;
  bool level_;
  bool recorded_from_level_;
  bool recording_ = true;
  std::vector<LineSample> writes_;
  Listener listener_;
};

// An EdgeInput driven by fire(). Strict: attach() fails when the line is marked unwired.
class SimEdgeInput final : public hal::EdgeInput {
 public:
  explicit SimEdgeInput(bool initial_level = false) : level_(initial_level) {}

  [[nodiscard]] bool attach(Handler handler, void* ctx) override;
  void detach() override;
  [[nodiscard]] bool read() const override { return level_; }

  // Test / model hook: the line goes to `level` at device time t_us and, if a handler is
  // attached, it is called as the board's interrupt would (even when the level does not
  // change, so tests can inject glitches and bounces).
  void fire(bool level, uint64_t t_us);
  // A pulse: active level at start_t_us, back at end_t_us (both edges delivered).
  void pulse(bool active_level, uint64_t start_t_us, uint64_t end_t_us);

  // Makes attach() fail, as on a board where the pin cannot interrupt.
  void set_wired(bool wired) { wired_ = wired; }
  [[nodiscard]] bool attached() const { return handler_ != nullptr; }
  [[nodiscard]] uint64_t edges_delivered() const { return delivered_; }

 private:
  Handler handler_ = nullptr;
  void* ctx_ = nullptr;
  bool level_;
  bool wired_ = true;
  uint64_t delivered_ = 0;
};

// A one-shot Alarm for virtual time. Nothing fires by itself: run_until() (or fire_if_due())
// moves the clock to each deadline and calls the handler there, so handlers see exact times.
class VirtualAlarm final : public hal::Alarm {
 public:
  void set_handler(Handler handler, void* ctx) override {
    handler_ = handler;
    ctx_ = ctx;
  }
  void arm_at(uint64_t t_us) override {
    armed_ = true;
    deadline_us_ = t_us;
  }
  void cancel() override { armed_ = false; }

  [[nodiscard]] bool armed() const { return armed_; }
  // Meaningful only while armed().
  [[nodiscard]] uint64_t deadline_us() const { return deadline_us_; }
  [[nodiscard]] uint64_t fired_count() const { return fired_; }

  // Fires once if armed and the deadline is <= clock time (a past deadline fires at the
  // clock's current time, as "at once" on hardware). Returns whether it fired.
  bool fire_if_due(const VirtualClock& clock);

  // Repeatedly: advance the clock to the next deadline <= t_end_us and fire (the handler may
  // re-arm), then leave the clock at t_end_us. Returns the number of firings. Stops after
  // max_fires so a handler that keeps re-arming in the past cannot hang a test.
  std::size_t run_until(VirtualClock& clock, uint64_t t_end_us, std::size_t max_fires = 1'000'000);

 private:
  Handler handler_ = nullptr;
  void* ctx_ = nullptr;
  bool armed_ = false;
  uint64_t deadline_us_ = 0;
  uint64_t fired_ = 0;
};

// Runs several alarms on one clock in deadline order (earliest first; ties in array order)
// up to t_end_us, leaving the clock there. Returns the number of firings.
std::size_t run_alarms_until(VirtualClock& clock, uint64_t t_end_us, VirtualAlarm* const* alarms,
                             std::size_t alarm_count, std::size_t max_fires = 1'000'000);

}  // namespace icgt::sim
