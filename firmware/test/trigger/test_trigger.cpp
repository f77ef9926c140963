// Trigger: exact shot times in virtual time for every mode, pulse widths and polarity on the
// recorded lines, refusals that change nothing, and the interrupt-to-loop record queue.
#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

#include "board/sim_gpio.hpp"
#include "board/virtual_clock.hpp"
#include "core/trigger.hpp"

namespace icgt::core {
namespace {

using sim::LineSample;

constexpr uint64_t kT0 = 10'000'000;  // capture start: not 0, so absolute vs relative mistakes show
constexpr uint32_t kMs = 1'000;

CaptureParams interval_params(uint32_t interval_us, uint32_t pulse_us, uint32_t focus_lead_us = 0) {
  CaptureParams p;
  p.mode = CaptureMode::interval;
  p.interval_us = interval_us;
  p.shutter_pulse_us = pulse_us;
  p.focus_lead_us = focus_lead_us;
  return p;
}

class TriggerTest : public ::testing::Test {
 protected:
  TriggerTest() {
    clock.set_us(kT0);
    shutter.clear();  // drop the constructor's "inactive" writes
    focus.clear();
  }

  std::vector<TriggerRecord> drain() {
    std::vector<TriggerRecord> out;
    TriggerRecord r;
    while (trigger.records().pop(r)) out.push_back(r);
    return out;
  }

  // Rising (active-high) or falling edge times of a recorded line.
  static std::vector<uint64_t> edge_times(const sim::RecordingDigitalOut& line, bool to_level) {
    std::vector<uint64_t> out;
    for (const LineSample& s : line.edges()) {
      if (s.level == to_level) out.push_back(s.t_us);
    }
    return out;
  }

  sim::VirtualClock clock;
  sim::VirtualAlarm alarm;
  sim::RecordingDigitalOut shutter{clock};
  sim::RecordingDigitalOut focus{clock};
  Trigger trigger{alarm, clock, shutter, focus};
};

TEST_F(TriggerTest, IntervalShotsLandExactlyOnStartPlusKTimesInterval) {
  ASSERT_EQ(trigger.start(interval_params(200 * kMs, 10 * kMs), kT0), TriggerResult::ok);
  EXPECT_EQ(trigger.state(), CaptureState::capturing);
  alarm.run_until(clock, kT0 + 1'000 * kMs);  // inclusive: shots k = 0..5

  std::vector<uint64_t> expected_rise;
  std::vector<uint64_t> expected_fall;
  for (uint64_t k = 0; k <= 5; ++k) {
    expected_rise.push_back(kT0 + k * 200 * kMs);
    if (k < 5) expected_fall.push_back(kT0 + k * 200 * kMs + 10 * kMs);
  }
  EXPECT_EQ(edge_times(shutter, true), expected_rise);
  EXPECT_EQ(edge_times(shutter, false), expected_fall);
  EXPECT_TRUE(shutter.level());  // the 6th pulse is still on at the end of the run

  const auto records = drain();
  ASSERT_EQ(records.size(), 6u);
  for (std::size_t i = 0; i < records.size(); ++i) {
    EXPECT_EQ(records[i].image_index, i + 1);
    EXPECT_EQ(records[i].trigger_t_us, expected_rise[i]);
    EXPECT_EQ(records[i].flags, 0u);
  }
  EXPECT_EQ(trigger.triggers_fired(), 6u);
  EXPECT_TRUE(focus.writes().empty());  // focus_lead_us = 0: the focus line is never touched
}

TEST_F(TriggerTest, IntervalGridDoesNotDriftOverAThousandShotsRunInUnevenSteps) {
  ASSERT_EQ(trigger.start(interval_params(200 * kMs, 5 * kMs), kT0), TriggerResult::ok);
  const uint64_t last_shot_t_us = kT0 + 999 * 200 * kMs;
  uint64_t t = kT0;
  for (int i = 0; t < last_shot_t_us; ++i) {
    t += 1'234 + static_cast<uint64_t>(i % 7) * 77'777;  // the loop never lines up with the grid
    if (t > last_shot_t_us) t = last_shot_t_us;
    alarm.run_until(clock, t);
    (void)drain();
  }
  const auto rises = edge_times(shutter, true);
  ASSERT_EQ(rises.size(), 1000u);
  for (std::size_t k = 0; k < rises.size(); ++k) ASSERT_EQ(rises[k], kT0 + k * 200 * kMs) << "shot " << k;
}

TEST_F(TriggerTest, LateInterruptDelaysOnlyItsOwnShotAndKeepsTheFullPulseWidth) {
  ASSERT_EQ(trigger.start(interval_params(100 * kMs, 20 * kMs), kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 50 * kMs);  // first shot and its pulse end
  ASSERT_TRUE(alarm.armed());
  ASSERT_EQ(alarm.deadline_us(), kT0 + 100 * kMs);
  clock.set_us(kT0 + 100 * kMs + 3 * kMs);  // the interrupt runs 3 ms late
  ASSERT_TRUE(alarm.fire_if_due(clock));
  alarm.run_until(clock, kT0 + 250 * kMs);

  EXPECT_EQ(edge_times(shutter, true),
            (std::vector<uint64_t>{kT0, kT0 + 103 * kMs, kT0 + 200 * kMs}));
  EXPECT_EQ(edge_times(shutter, false),
            (std::vector<uint64_t>{kT0 + 20 * kMs, kT0 + 123 * kMs, kT0 + 220 * kMs}));
  const auto records = drain();
  ASSERT_EQ(records.size(), 3u);
  EXPECT_EQ(records[1].trigger_t_us, kT0 + 103 * kMs);  // the time the line really went active
}

TEST_F(TriggerTest, FocusLeadAssertsFocusBeforeTheFirstShotAndHoldsItUntilStop) {
  ASSERT_EQ(trigger.start(interval_params(200 * kMs, 100 * kMs, 500 * kMs), kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 950 * kMs);
  EXPECT_EQ(edge_times(focus, true), std::vector<uint64_t>{kT0});
  EXPECT_EQ(edge_times(shutter, true),
            (std::vector<uint64_t>{kT0 + 500 * kMs, kT0 + 700 * kMs, kT0 + 900 * kMs}));
  EXPECT_TRUE(focus.level());

  ASSERT_EQ(trigger.stop(), TriggerResult::ok);
  EXPECT_FALSE(focus.level());
  EXPECT_FALSE(shutter.level());  // the pulse in progress was cut at stop
  EXPECT_EQ(edge_times(shutter, false).back(), kT0 + 950 * kMs);
  EXPECT_EQ(trigger.state(), CaptureState::idle);
  EXPECT_FALSE(alarm.armed());
  alarm.run_until(clock, kT0 + 5'000 * kMs);
  EXPECT_EQ(trigger.triggers_fired(), 3u);  // nothing fires after stop
}

TEST_F(TriggerTest, FocusBurstFollowsThePapersCycleAndRepeats) {
  CaptureParams p;
  p.mode = CaptureMode::focus_burst;
  p.focus_lead_us = 500 * kMs;
  p.interval_us = 200 * kMs;  // 5 fps
  p.burst_us = 2'000 * kMs;
  p.shutter_pulse_us = 50 * kMs;
  ASSERT_EQ(trigger.start(p, kT0), TriggerResult::ok);
  const uint64_t cycle_us = 2'500 * kMs;  // focus lead + 10 shots * 200 ms
  alarm.run_until(clock, kT0 + 2 * cycle_us - 1);

  std::vector<uint64_t> expected_shots;
  for (uint64_t c = 0; c < 2; ++c) {
    for (uint64_t k = 0; k < 10; ++k) expected_shots.push_back(kT0 + c * cycle_us + 500 * kMs + k * 200 * kMs);
  }
  EXPECT_EQ(edge_times(shutter, true), expected_shots);
  // Focus half-pressed 500 ms before each burst's first shot, released when its last
  // pulse (at +2.3 s) ends, pressed again for the next cycle.
  EXPECT_EQ(edge_times(focus, true), (std::vector<uint64_t>{kT0, kT0 + cycle_us}));
  EXPECT_EQ(edge_times(focus, false),
            (std::vector<uint64_t>{kT0 + 2'350 * kMs, kT0 + cycle_us + 2'350 * kMs}));

  const auto records = drain();
  ASSERT_EQ(records.size(), 20u);
  for (std::size_t i = 0; i < records.size(); ++i) {
    EXPECT_EQ(records[i].image_index, i + 1);
    EXPECT_EQ(records[i].trigger_t_us, expected_shots[i]);
    EXPECT_EQ(records[i].flags, 1u << 4);  // ExposureFlags.focus_cycle
  }
  // Ten shots fall within each 2 s burst window.
  for (uint64_t c = 0; c < 2; ++c) {
    const uint64_t burst_start = kT0 + c * cycle_us + 500 * kMs;
    EXPECT_LT(expected_shots[c * 10 + 9], burst_start + 2'000 * kMs);
  }
  EXPECT_EQ(trigger.state(), CaptureState::capturing);
}

TEST_F(TriggerTest, SingleShotFiresOnceThenFinishesAndReleasesFocus) {
  CaptureParams p;
  p.mode = CaptureMode::single;
  p.interval_us = 0;  // unused by single
  p.focus_lead_us = 300 * kMs;
  p.shutter_pulse_us = 100 * kMs;
  ASSERT_EQ(trigger.start(p, kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 399 * kMs);
  EXPECT_EQ(trigger.state(), CaptureState::capturing);  // pulse still on
  alarm.run_until(clock, kT0 + 10'000 * kMs);

  EXPECT_EQ(edge_times(focus, true), std::vector<uint64_t>{kT0});
  EXPECT_EQ(edge_times(shutter, true), std::vector<uint64_t>{kT0 + 300 * kMs});
  EXPECT_EQ(edge_times(shutter, false), std::vector<uint64_t>{kT0 + 400 * kMs});
  EXPECT_EQ(edge_times(focus, false), std::vector<uint64_t>{kT0 + 400 * kMs});
  EXPECT_EQ(trigger.state(), CaptureState::finished);
  EXPECT_FALSE(alarm.armed());
  EXPECT_EQ(trigger.triggers_fired(), 1u);
  EXPECT_EQ(trigger.stop(), TriggerResult::not_capturing);
}

TEST_F(TriggerTest, CountModeFiresExactlyNShotsThenFinishes) {
  CaptureParams p = interval_params(100 * kMs, 30 * kMs);
  p.mode = CaptureMode::count;
  p.count = 4;
  ASSERT_EQ(trigger.start(p, kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 320 * kMs);
  EXPECT_EQ(trigger.state(), CaptureState::capturing);  // 4th pulse (300..330 ms) in progress
  alarm.run_until(clock, kT0 + 330 * kMs);
  EXPECT_EQ(trigger.state(), CaptureState::finished);
  alarm.run_until(clock, kT0 + 5'000 * kMs);

  EXPECT_EQ(edge_times(shutter, true),
            (std::vector<uint64_t>{kT0, kT0 + 100 * kMs, kT0 + 200 * kMs, kT0 + 300 * kMs}));
  EXPECT_EQ(edge_times(shutter, false),
            (std::vector<uint64_t>{kT0 + 30 * kMs, kT0 + 130 * kMs, kT0 + 230 * kMs, kT0 + 330 * kMs}));
  EXPECT_EQ(trigger.triggers_fired(), 4u);
  EXPECT_EQ(drain().size(), 4u);
}

TEST_F(TriggerTest, ImageIndexKeepsCountingAcrossCaptures) {
  CaptureParams p = interval_params(100 * kMs, 30 * kMs);
  p.mode = CaptureMode::count;
  p.count = 2;
  ASSERT_EQ(trigger.start(p, kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 1'000 * kMs);
  ASSERT_EQ(trigger.state(), CaptureState::finished);
  ASSERT_EQ(trigger.start(p, clock.now_us()), TriggerResult::ok);  // finished -> start again
  alarm.run_until(clock, kT0 + 2'000 * kMs);
  const auto records = drain();
  ASSERT_EQ(records.size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) EXPECT_EQ(records[i].image_index, i + 1);
  EXPECT_EQ(records[2].trigger_t_us, kT0 + 1'000 * kMs);
  EXPECT_EQ(trigger.last_image_index(), 4u);
}

TEST_F(TriggerTest, ActiveLowLinesIdleHighAndPulseLowForTheConfiguredWidth) {
  ASSERT_EQ(trigger.set_polarity({false, false}), TriggerResult::ok);
  EXPECT_TRUE(shutter.level());
  EXPECT_TRUE(focus.level());
  shutter.clear();
  focus.clear();

  ASSERT_EQ(trigger.start(interval_params(250 * kMs, 40 * kMs, 100 * kMs), kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 700 * kMs);
  EXPECT_EQ(edge_times(focus, false), std::vector<uint64_t>{kT0});
  EXPECT_EQ(edge_times(shutter, false),
            (std::vector<uint64_t>{kT0 + 100 * kMs, kT0 + 350 * kMs, kT0 + 600 * kMs}));
  EXPECT_EQ(edge_times(shutter, true),
            (std::vector<uint64_t>{kT0 + 140 * kMs, kT0 + 390 * kMs, kT0 + 640 * kMs}));
  ASSERT_EQ(trigger.stop(), TriggerResult::ok);
  EXPECT_TRUE(shutter.level());  // released = high for active-low
  EXPECT_TRUE(focus.level());
}

TEST_F(TriggerTest, StartWhileCapturingIsRefusedBusyAndChangesNothing) {
  ASSERT_EQ(trigger.start(interval_params(200 * kMs, 10 * kMs), kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 50 * kMs);
  const CaptureParams other = interval_params(100 * kMs, 20 * kMs, 300 * kMs);
  EXPECT_EQ(trigger.start(other, clock.now_us()), TriggerResult::busy_capturing);
  EXPECT_EQ(trigger.params().interval_us, 200 * kMs);
  EXPECT_EQ(alarm.deadline_us(), kT0 + 200 * kMs);
  alarm.run_until(clock, kT0 + 600 * kMs);
  EXPECT_EQ(edge_times(shutter, true),
            (std::vector<uint64_t>{kT0, kT0 + 200 * kMs, kT0 + 400 * kMs, kT0 + 600 * kMs}));
  EXPECT_TRUE(focus.writes().empty());
}

TEST_F(TriggerTest, SetPolarityWhileCapturingIsRefusedBusy) {
  ASSERT_EQ(trigger.start(interval_params(200 * kMs, 10 * kMs), kT0), TriggerResult::ok);
  EXPECT_EQ(trigger.set_polarity({false, false}), TriggerResult::busy_capturing);
  EXPECT_TRUE(trigger.polarity().shutter_active_high);
}

TEST_F(TriggerTest, StopWhileIdleIsRefusedNotCapturing) {
  EXPECT_EQ(trigger.stop(), TriggerResult::not_capturing);
  EXPECT_EQ(trigger.state(), CaptureState::idle);
  EXPECT_TRUE(shutter.writes().empty());
  EXPECT_TRUE(focus.writes().empty());
}

struct RefusedCase {
  const char* name;
  CaptureParams params;
};

CaptureParams with(CaptureParams p, CaptureMode mode, uint32_t count = 0, uint32_t burst_us = 0) {
  p.mode = mode;
  p.count = count;
  p.burst_us = burst_us;
  return p;
}

TEST_F(TriggerTest, OutOfRangeParametersAreRefusedAndChangeNothing) {
  const CaptureParams good = interval_params(200 * kMs, 10 * kMs);
  const RefusedCase cases[] = {
      {"interval below 50 ms", interval_params(49'999, 10 * kMs)},
      {"interval above 3600 s", interval_params(3'600'000'001u, 10 * kMs)},
      {"pulse below 1 ms", interval_params(200 * kMs, 999)},
      {"pulse above 1 s", interval_params(2'000 * kMs, 1'000'001)},
      {"pulse equal to interval", interval_params(100 * kMs, 100 * kMs)},
      {"count mode with count 0", with(good, CaptureMode::count, 0)},
      {"burst shorter than interval", with(good, CaptureMode::focus_burst, 0, 199'999)},
      {"single with pulse 0", with(interval_params(0, 0), CaptureMode::single)},
      {"mode 0", with(good, static_cast<CaptureMode>(0))},
      {"mode 5", with(good, static_cast<CaptureMode>(5))},
  };
  for (const RefusedCase& c : cases) {
    EXPECT_EQ(Trigger::validate(c.params), TriggerResult::out_of_range) << c.name;
    EXPECT_EQ(trigger.start(c.params, kT0), TriggerResult::out_of_range) << c.name;
    EXPECT_EQ(trigger.state(), CaptureState::idle) << c.name;
    EXPECT_FALSE(alarm.armed()) << c.name;
  }
  alarm.run_until(clock, kT0 + 10'000 * kMs);
  EXPECT_TRUE(shutter.writes().empty());
  EXPECT_TRUE(focus.writes().empty());
  EXPECT_EQ(trigger.triggers_fired(), 0u);
  EXPECT_EQ(trigger.params().interval_us, 0u);  // never accepted anything
}

TEST_F(TriggerTest, LimitValuesAreAccepted) {
  EXPECT_EQ(Trigger::validate(interval_params(50 * kMs, 1 * kMs)), TriggerResult::ok);
  EXPECT_EQ(Trigger::validate(interval_params(3'600'000'000u, 1'000 * kMs)), TriggerResult::ok);
  EXPECT_EQ(Trigger::validate(interval_params(50 * kMs, 50 * kMs - 1)), TriggerResult::ok);
  EXPECT_EQ(Trigger::validate(with(interval_params(200 * kMs, 10 * kMs), CaptureMode::count, 1)),
            TriggerResult::ok);
  EXPECT_EQ(Trigger::validate(with(interval_params(200 * kMs, 10 * kMs), CaptureMode::focus_burst, 0, 200 * kMs)),
            TriggerResult::ok);
}

TEST_F(TriggerTest, FullRecordQueueCountsDropsButEveryShotStillFires) {
  ASSERT_EQ(trigger.start(interval_params(50 * kMs, 5 * kMs), kT0), TriggerResult::ok);
  alarm.run_until(clock, kT0 + 39 * 50 * kMs);  // 40 shots, loop never drains
  EXPECT_EQ(trigger.triggers_fired(), 40u);
  EXPECT_EQ(edge_times(shutter, true).size(), 40u);
  EXPECT_EQ(trigger.records().pushed(), kTriggerQueueCapacity);
  EXPECT_EQ(trigger.records().dropped(), 40u - kTriggerQueueCapacity);
  const auto records = drain();
  EXPECT_EQ(records.front().image_index, 1u);  // the oldest are kept
  EXPECT_EQ(records.back().image_index, kTriggerQueueCapacity);
}

}  // namespace
}  // namespace icgt::core
