// The simulated camera's hand-pressed shots: "between triggers" shots are taken half-way between two
// triggered exposures whatever the trigger's phase, numbered in the order they are exposed, and taken
// at once when no steady trigger runs.
#include <gtest/gtest.h>

#include <cstdint>

#include "devices/camera_model.hpp"

namespace {

using icgt::sim::CameraModel;
using icgt::sim::CameraModelConfig;

CameraModelConfig steady() {
  CameraModelConfig c;
  c.latency_us = 48'000;
  c.latency_jitter_us = 0;
  return c;
}

void pulse(CameraModel& cam, uint64_t t_us) {
  cam.on_shutter_line(true, t_us);
  cam.on_shutter_line(false, t_us + 10'000);
}

TEST(CameraModelManualShot, BetweenTriggersLandsHalfWayWhateverThePressPhase) {
  for (uint64_t press_phase_us : {1'000u, 60'000u, 130'000u, 199'000u}) {
    CameraModel cam(steady());
    pulse(cam, 1'000'000);
    pulse(cam, 1'200'000);
    cam.manual_shot_between_triggers(1'200'000 + press_phase_us);
    cam.release_held_manual_shot(1'200'000 + press_phase_us + 1);
    pulse(cam, 1'400'000);
    pulse(cam, 1'600'000);
    const auto& ex = cam.exposures();
    ASSERT_EQ(ex.size(), 5u) << press_phase_us;
    // numbered in exposure order: trigger 3's exposure, then the manual shot, then trigger 4's
    EXPECT_FALSE(ex[2].manual);
    EXPECT_TRUE(ex[3].manual);
    EXPECT_EQ(ex[3].start_t_us, 1'400'000u + (48'000u + 200'000u) / 2) << press_phase_us;
    EXPECT_LT(ex[2].start_t_us, ex[3].start_t_us);
    EXPECT_LT(ex[3].start_t_us, ex[4].start_t_us);
  }
}

TEST(CameraModelManualShot, WithoutASteadyTriggerTheShotIsTakenAtOnce) {
  CameraModel cam(steady());
  cam.manual_shot_between_triggers(500'000);  // no trigger yet
  ASSERT_EQ(cam.exposures().size(), 1u);
  EXPECT_EQ(cam.exposures()[0].start_t_us, 500'000u);

  pulse(cam, 1'000'000);
  pulse(cam, 1'200'000);
  cam.manual_shot_between_triggers(1'250'000);  // held for the next trigger ...
  cam.release_held_manual_shot(1'500'000);      // ... which does not come (capture stopped)
  EXPECT_EQ(cam.exposures().size(), 3u);
  cam.release_held_manual_shot(1'600'001);  // two periods after the last trigger: taken now
  ASSERT_EQ(cam.exposures().size(), 4u);
  EXPECT_TRUE(cam.exposures()[3].manual);
  EXPECT_EQ(cam.exposures()[3].start_t_us, 1'600'001u);
  cam.release_held_manual_shot(1'700'000);
  EXPECT_EQ(cam.exposures().size(), 4u);  // once
}

}  // namespace
