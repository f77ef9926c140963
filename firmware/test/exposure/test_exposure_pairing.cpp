// ExposurePairing: trigger/feedback pairing with missed, extra and stray edges, the
// feedback and end timeouts, the no-feedback-line mode, polarity, and an end-to-end run
// with the real Trigger on virtual time.
#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

#include "board/sim_gpio.hpp"
#include "board/virtual_clock.hpp"
#include "core/exposure_pairing.hpp"
#include "core/trigger.hpp"

namespace icgt::core {
namespace {

constexpr uint64_t kMs = 1'000;
constexpr uint64_t kT = 50'000'000;  // first trigger

class ExposurePairingTest : public ::testing::Test {
 protected:
  // Active-low hot shoe (the usual case), 100 ms timeout, 1 s end timeout.
  void enable(bool active_high = false, uint32_t timeout_us = 100 * kMs, uint32_t end_timeout_us = 1'000 * kMs) {
    FeedbackConfig c;
    c.enabled = true;
    c.active_high = active_high;
    c.timeout_us = timeout_us;
    c.end_timeout_us = end_timeout_us;
    ASSERT_EQ(pairing.configure(c), FeedbackResult::ok);
  }

  void trigger_at(uint32_t index, uint64_t t_us, uint8_t flags = 0) {
    TriggerRecord r;
    r.image_index = index;
    r.camera_id = 0;
    r.flags = flags;
    r.trigger_t_us = t_us;
    ASSERT_TRUE(triggers.push(r));
  }

  // The camera's hot shoe: active (low) for the exposure.
  void exposure_at(uint64_t start_t_us, uint64_t end_t_us, bool active_high = false) {
    line.pulse(active_high, start_t_us, end_t_us);
  }

  std::vector<Exposure> poll(uint64_t now_us) {
    std::vector<Exposure> all;
    Exposure out[4];
    std::size_t n = 0;
    do {
      n = pairing.poll(now_us, out, 4);
      all.insert(all.end(), out, out + n);
    } while (n == 4);
    return all;
  }

  TriggerQueue triggers;
  sim::SimEdgeInput line{true};  // idles high (active-low line released)
  ExposurePairing pairing{triggers, &line, 0};
};

TEST_F(ExposurePairingTest, WithoutAFeedbackLineEveryTriggerIsEmittedAtOnceFlaggedNoFeedbackLine) {
  trigger_at(1, kT);
  trigger_at(2, kT + 200 * kMs, exposure_flags::focus_cycle);
  const auto out = poll(kT + 200 * kMs);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].flags, exposure_flags::no_feedback_line);
  EXPECT_EQ(out[0].trigger_t_us, kT);
  EXPECT_EQ(out[0].feedback_start_t_us, 0u);
  EXPECT_EQ(out[0].feedback_end_t_us, 0u);
  EXPECT_EQ(out[0].duration_us, 0u);
  EXPECT_EQ(out[1].flags, exposure_flags::no_feedback_line | exposure_flags::focus_cycle);
  EXPECT_EQ(pairing.exposures_confirmed(), 0u);
  EXPECT_EQ(pairing.feedback_missing(), 0u);
  EXPECT_FALSE(line.attached());
}

TEST_F(ExposurePairingTest, PairsATriggerWithItsFeedbackPulseAndMeasuresTheDuration) {
  enable();
  trigger_at(1, kT);
  exposure_at(kT + 42 * kMs, kT + 42 * kMs + 8'333);
  const auto out = poll(kT + 60 * kMs);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].flags, 0u);
  EXPECT_EQ(out[0].trigger_t_us, kT);
  EXPECT_EQ(out[0].feedback_start_t_us, kT + 42 * kMs);
  EXPECT_EQ(out[0].feedback_end_t_us, kT + 42 * kMs + 8'333);
  EXPECT_EQ(out[0].duration_us, 8'333u);
  EXPECT_EQ(pairing.exposures_confirmed(), 1u);
}

TEST_F(ExposurePairingTest, ExposureIsHeldBackUntilItsEndEdgeArrives) {
  enable();
  trigger_at(1, kT);
  line.fire(false, kT + 40 * kMs);
  EXPECT_TRUE(poll(kT + 45 * kMs).empty());
  line.fire(true, kT + 50 * kMs);
  const auto out = poll(kT + 55 * kMs);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].duration_us, 10'000u);
}

TEST_F(ExposurePairingTest, TriggerWithoutFeedbackIsReportedMissingOnlyAfterTheTimeout) {
  enable();
  trigger_at(7, kT);
  EXPECT_TRUE(poll(kT + 100 * kMs).empty());  // exactly at the timeout an edge may still count
  const auto out = poll(kT + 100 * kMs + 1);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].image_index, 7u);
  EXPECT_EQ(out[0].flags, exposure_flags::feedback_missing);
  EXPECT_EQ(out[0].trigger_t_us, kT);
  EXPECT_EQ(out[0].feedback_start_t_us, 0u);
  EXPECT_EQ(pairing.feedback_missing(), 1u);
  EXPECT_EQ(pairing.exposures_confirmed(), 0u);
}

TEST_F(ExposurePairingTest, LatePollStillPairsAFeedbackEdgeThatArrivedInTime) {
  enable();
  trigger_at(1, kT);
  exposure_at(kT + 99 * kMs, kT + 105 * kMs);
  const auto out = poll(kT + 5'000 * kMs);  // the loop was stalled for seconds
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].flags, 0u);
  EXPECT_EQ(out[0].feedback_start_t_us, kT + 99 * kMs);
}

TEST_F(ExposurePairingTest, FeedbackAfterTheTimeoutIsMissingPlusAnUnsolicitedExposure) {
  enable();
  trigger_at(1, kT);
  exposure_at(kT + 150 * kMs, kT + 160 * kMs);
  const auto out = poll(kT + 200 * kMs);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].flags, exposure_flags::feedback_missing);
  EXPECT_EQ(out[1].image_index, 0u);
  EXPECT_EQ(out[1].flags, exposure_flags::unsolicited);
  EXPECT_EQ(out[1].feedback_start_t_us, kT + 150 * kMs);
}

TEST_F(ExposurePairingTest, MissedFeedbackDoesNotShiftThePairingOfLaterShots) {
  enable();
  for (uint32_t i = 0; i < 4; ++i) trigger_at(i + 1, kT + i * 200 * kMs);
  exposure_at(kT + 40 * kMs, kT + 48 * kMs);
  // shot 2 (kT + 200 ms) never exposes
  exposure_at(kT + 440 * kMs, kT + 448 * kMs);
  exposure_at(kT + 641 * kMs, kT + 649 * kMs);
  const auto out = poll(kT + 1'000 * kMs);
  ASSERT_EQ(out.size(), 4u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].feedback_start_t_us, kT + 40 * kMs);
  EXPECT_EQ(out[1].image_index, 2u);
  EXPECT_EQ(out[1].flags, exposure_flags::feedback_missing);
  EXPECT_EQ(out[2].image_index, 3u);
  EXPECT_EQ(out[2].feedback_start_t_us, kT + 440 * kMs);
  EXPECT_EQ(out[3].image_index, 4u);
  EXPECT_EQ(out[3].feedback_start_t_us, kT + 641 * kMs);
  EXPECT_EQ(pairing.exposures_confirmed(), 3u);
  EXPECT_EQ(pairing.feedback_missing(), 1u);
}

TEST_F(ExposurePairingTest, ExtraPulseWithoutATriggerIsUnsolicitedWithImageIndexZero) {
  enable();
  trigger_at(1, kT);
  exposure_at(kT + 40 * kMs, kT + 48 * kMs);
  exposure_at(kT + 120 * kMs, kT + 130 * kMs);  // manual shot
  const auto out = poll(kT + 300 * kMs);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[1].image_index, 0u);
  EXPECT_EQ(out[1].flags, exposure_flags::unsolicited);
  EXPECT_EQ(out[1].trigger_t_us, 0u);
  EXPECT_EQ(out[1].feedback_start_t_us, kT + 120 * kMs);
  EXPECT_EQ(out[1].feedback_end_t_us, kT + 130 * kMs);
  EXPECT_EQ(out[1].duration_us, 10'000u);
  EXPECT_EQ(pairing.feedback_unsolicited(), 1u);
  EXPECT_EQ(pairing.exposures_confirmed(), 1u);
}

TEST_F(ExposurePairingTest, FeedbackBeforeATriggerIsNeverPairedWithIt) {
  enable();
  exposure_at(kT - 30 * kMs, kT - 20 * kMs);  // a manual shot just before the trigger
  trigger_at(1, kT);
  const auto out = poll(kT + 500 * kMs);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].flags, exposure_flags::unsolicited);
  EXPECT_EQ(out[1].image_index, 1u);
  EXPECT_EQ(out[1].flags, exposure_flags::feedback_missing);
}

TEST_F(ExposurePairingTest, StartWithoutEndIsEmittedEndMissingAfterTheEndTimeout) {
  enable(false, 100 * kMs, 500 * kMs);
  trigger_at(1, kT);
  line.fire(false, kT + 40 * kMs);
  EXPECT_TRUE(poll(kT + 540 * kMs).empty());
  const auto out = poll(kT + 540 * kMs + 1);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].flags, exposure_flags::end_missing);
  EXPECT_EQ(out[0].feedback_start_t_us, kT + 40 * kMs);
  EXPECT_EQ(out[0].feedback_end_t_us, 0u);
  EXPECT_EQ(out[0].duration_us, 0u);
  EXPECT_EQ(pairing.exposures_confirmed(), 1u);  // the start was seen
  EXPECT_EQ(pairing.end_missing(), 1u);
}

TEST_F(ExposurePairingTest, SecondStartBeforeAnEndClosesTheFirstAsEndMissing) {
  enable();
  trigger_at(1, kT);
  trigger_at(2, kT + 200 * kMs);
  line.fire(false, kT + 40 * kMs);  // start of 1; its end edge is lost
  exposure_at(kT + 240 * kMs, kT + 250 * kMs);
  const auto out = poll(kT + 300 * kMs);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].flags, exposure_flags::end_missing);
  EXPECT_EQ(out[1].image_index, 2u);
  EXPECT_EQ(out[1].flags, 0u);
  EXPECT_EQ(out[1].duration_us, 10'000u);
}

TEST_F(ExposurePairingTest, StrayEndEdgeIsIgnoredAndCounted) {
  enable();
  line.fire(true, kT - 10 * kMs);  // release with nothing open (e.g. low at attach)
  trigger_at(1, kT);
  exposure_at(kT + 40 * kMs, kT + 50 * kMs);
  const auto out = poll(kT + 100 * kMs);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].flags, 0u);
  EXPECT_EQ(pairing.stray_edges(), 1u);
}

TEST_F(ExposurePairingTest, ActiveHighPolarityTreatsRisingEdgesAsStarts) {
  enable(true);
  trigger_at(1, kT);
  exposure_at(kT + 30 * kMs, kT + 35 * kMs, true);
  const auto out = poll(kT + 100 * kMs);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].feedback_start_t_us, kT + 30 * kMs);
  EXPECT_EQ(out[0].duration_us, 5'000u);
}

TEST_F(ExposurePairingTest, SmallOutputArrayLosesNothingAcrossPolls) {
  enable();
  for (uint32_t i = 0; i < 5; ++i) trigger_at(i + 1, kT + i * 200 * kMs);
  std::vector<Exposure> all;
  Exposure one[1];
  for (int i = 0; i < 20; ++i) {
    const std::size_t n = pairing.poll(kT + 2'000 * kMs, one, 1);
    ASSERT_LE(n, 1u);
    if (n == 1) all.push_back(one[0]);
  }
  ASSERT_EQ(all.size(), 5u);
  for (uint32_t i = 0; i < 5; ++i) {
    EXPECT_EQ(all[i].image_index, i + 1);
    EXPECT_EQ(all[i].flags, exposure_flags::feedback_missing);
  }
}

TEST_F(ExposurePairingTest, FocusCycleFlagIsCarriedOverFromTheTrigger) {
  enable();
  trigger_at(1, kT, exposure_flags::focus_cycle);
  exposure_at(kT + 30 * kMs, kT + 35 * kMs);
  const auto out = poll(kT + 100 * kMs);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].flags, exposure_flags::focus_cycle);
}

// 20 fps, a shutter lag of 60 ms (longer than the 50 ms interval): every edge arrives after
// the next trigger fired. With the camera's shortest lag (55 ms) configured the window
// [55, 95] ms is shorter than the interval: the ignored trigger 2 times out before trigger 3's
// edge, and nothing shifts.
TEST_F(ExposurePairingTest, ShutterLagLongerThanTheIntervalPairsInOrderAndAMissDoesNotShift) {
  FeedbackConfig c;
  c.enabled = true;
  c.timeout_us = 95 * kMs;
  c.min_lag_us = 55 * kMs;
  ASSERT_EQ(pairing.configure(c), FeedbackResult::ok);
  for (uint32_t i = 1; i <= 5; ++i) trigger_at(i, kT + (i - 1) * 50 * kMs);
  for (uint32_t i = 1; i <= 5; ++i) {
    if (i == 2) continue;  // the camera ignored trigger 2
    const uint64_t start = kT + (i - 1) * 50 * kMs + 60 * kMs;
    exposure_at(start, start + 1 * kMs);
  }
  const auto out = poll(kT + 600 * kMs);
  ASSERT_EQ(out.size(), 5u);
  for (uint32_t i = 1; i <= 5; ++i) {
    const Exposure& e = out[i - 1];
    EXPECT_EQ(e.image_index, i);
    if (i == 2) {
      EXPECT_EQ(e.flags, exposure_flags::feedback_missing);
    } else {
      EXPECT_EQ(e.flags, 0u) << i;
      EXPECT_EQ(e.feedback_start_t_us, e.trigger_t_us + 60 * kMs) << i;
    }
  }
}

TEST_F(ExposurePairingTest, AnEdgeSoonerThanTheShortestLagAfterEveryTriggerIsAManualShot) {
  FeedbackConfig c;
  c.enabled = true;
  c.timeout_us = 95 * kMs;
  c.min_lag_us = 40 * kMs;
  ASSERT_EQ(pairing.configure(c), FeedbackResult::ok);
  trigger_at(1, kT);
  exposure_at(kT + 10 * kMs, kT + 11 * kMs);  // 10 ms after the trigger: not its exposure
  exposure_at(kT + 45 * kMs, kT + 46 * kMs);
  const auto out = poll(kT + 300 * kMs);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].flags, exposure_flags::unsolicited);
  EXPECT_EQ(out[0].image_index, 0u);
  EXPECT_EQ(out[1].image_index, 1u);
  EXPECT_EQ(out[1].feedback_start_t_us, kT + 45 * kMs);
}

TEST_F(ExposurePairingTest, AMinimumLagNotBelowTheTimeoutIsRefused) {
  FeedbackConfig c;
  c.enabled = true;
  c.timeout_us = 100 * kMs;
  c.min_lag_us = 100 * kMs;
  EXPECT_EQ(pairing.configure(c), FeedbackResult::out_of_range);
  c.timeout_us = 2'000 * kMs;
  c.min_lag_us = 1'001 * kMs;
  EXPECT_EQ(pairing.configure(c), FeedbackResult::out_of_range);
  EXPECT_FALSE(pairing.feedback_enabled());
}

TEST_F(ExposurePairingTest, InvalidConfigurationIsRefusedAndChangesNothing) {
  FeedbackConfig c;
  c.enabled = true;
  c.timeout_us = 999;
  EXPECT_EQ(pairing.configure(c), FeedbackResult::out_of_range);
  c.timeout_us = 2'000'001;
  EXPECT_EQ(pairing.configure(c), FeedbackResult::out_of_range);
  c.timeout_us = 100'000;
  c.end_timeout_us = 0;
  EXPECT_EQ(pairing.configure(c), FeedbackResult::out_of_range);
  EXPECT_FALSE(pairing.feedback_enabled());
  EXPECT_FALSE(line.attached());

  c.end_timeout_us = 1'000'000;
  ExposurePairing no_line(triggers, nullptr);
  EXPECT_EQ(no_line.configure(c), FeedbackResult::not_supported);
  EXPECT_FALSE(no_line.feedback_enabled());
  sim::SimEdgeInput unwired;
  unwired.set_wired(false);
  ExposurePairing bad_line(triggers, &unwired);
  EXPECT_EQ(bad_line.configure(c), FeedbackResult::not_supported);
  EXPECT_FALSE(bad_line.feedback_enabled());
}

TEST_F(ExposurePairingTest, DisablingTheLineFlushesWaitingTriggersAsNoFeedbackLine) {
  enable();
  trigger_at(1, kT);
  line.fire(false, kT + 40 * kMs);  // exposure 1 open
  trigger_at(2, kT + 200 * kMs);
  EXPECT_TRUE(poll(kT + 210 * kMs).empty());
  ASSERT_EQ(pairing.configure(FeedbackConfig{}), FeedbackResult::ok);
  EXPECT_FALSE(line.attached());
  const auto out = poll(kT + 220 * kMs);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].image_index, 1u);
  EXPECT_EQ(out[0].flags, exposure_flags::end_missing);
  EXPECT_EQ(out[1].image_index, 2u);
  EXPECT_EQ(out[1].flags, exposure_flags::no_feedback_line);
}

TEST_F(ExposurePairingTest, FullEdgeQueueCountsDrops) {
  enable();
  for (uint64_t i = 0; i < kFeedbackQueueCapacity + 6; ++i) line.fire(i % 2 != 0, kT + i * kMs);
  EXPECT_EQ(pairing.edges().dropped(), 6u);
  EXPECT_EQ(pairing.edges().pushed(), kFeedbackQueueCapacity);
}

// End to end on virtual time: the real Trigger at 5 fps, a camera that exposes 35 ms after
// each shutter edge for 1/125 s but misses the third shot, and one manual shot.
TEST(ExposurePairingWithTrigger, EveryShotIsConfirmedOrFlaggedAtFiveFramesPerSecond) {
  sim::VirtualClock clock(kT);
  sim::VirtualAlarm alarm;
  sim::RecordingDigitalOut shutter(clock);
  sim::RecordingDigitalOut focus(clock);
  sim::SimEdgeInput hot_shoe(true);
  Trigger trigger(alarm, clock, shutter, focus);
  ExposurePairing pairing(trigger.records(), &hot_shoe);
  FeedbackConfig fc;
  fc.enabled = true;
  fc.timeout_us = 150'000;
  ASSERT_EQ(pairing.configure(fc), FeedbackResult::ok);

  // The camera model: schedules its hot-shoe edges when it sees the shutter go active.
  struct CameraEdge {
    uint64_t t_us;
    bool level;
  };
  std::vector<CameraEdge> camera_edges;  // appended in time order
  int shots_seen = 0;
  shutter.set_listener([&](bool level, uint64_t t_us) {
    if (!level) return;
    if (++shots_seen == 3) return;  // the camera misses the third shot
    camera_edges.push_back({t_us + 35'000, false});
    camera_edges.push_back({t_us + 43'000, true});
  });
  CaptureParams p;
  p.mode = CaptureMode::count;
  p.count = 5;
  p.interval_us = 200'000;
  p.shutter_pulse_us = 20'000;
  ASSERT_EQ(trigger.start(p, kT), TriggerResult::ok);

  std::vector<Exposure> got;
  Exposure out[8];
  std::size_t next_edge = 0;
  // The loop runs every 10 ms; the camera's edges are delivered when they happen.
  for (uint64_t t = kT; t <= kT + 1'500'000; t += 10'000) {
    alarm.run_until(clock, t);
    for (; next_edge < camera_edges.size() && camera_edges[next_edge].t_us <= t; ++next_edge) {
      hot_shoe.fire(camera_edges[next_edge].level, camera_edges[next_edge].t_us);
    }
    if (t == kT + 1'300'000) hot_shoe.pulse(false, t - 5'000, t - 1'000);  // manual shot
    const std::size_t n = pairing.poll(clock.now_us(), out, 8);
    got.insert(got.end(), out, out + n);
  }

  ASSERT_EQ(trigger.state(), CaptureState::finished);
  ASSERT_EQ(got.size(), 6u);
  const uint32_t expected_index[] = {1, 2, 3, 4, 5, 0};
  for (std::size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i].image_index, expected_index[i]) << i;
  for (const Exposure& x : got) {
    if (x.image_index == 3) {
      EXPECT_EQ(x.flags, exposure_flags::feedback_missing);
    } else if (x.image_index == 0) {
      EXPECT_EQ(x.flags, exposure_flags::unsolicited);
    } else {
      EXPECT_EQ(x.flags, 0u);
      EXPECT_EQ(x.trigger_t_us, kT + (x.image_index - 1) * 200'000u);
      EXPECT_EQ(x.feedback_start_t_us, x.trigger_t_us + 35'000);
      EXPECT_EQ(x.duration_us, 8'000u);
    }
  }
  EXPECT_EQ(pairing.exposures_confirmed(), 4u);
  EXPECT_EQ(pairing.feedback_missing(), 1u);
  EXPECT_EQ(pairing.feedback_unsolicited(), 1u);
  EXPECT_EQ(trigger.triggers_fired(), 5u);
}

}  // namespace
}  // namespace icgt::core
