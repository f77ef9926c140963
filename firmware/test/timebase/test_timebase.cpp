// Timebase: RTC rollover anchoring and its stated resolution, SET_TIME and its refusals,
// RTC phase alignment, and PPS counting and lock.
#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

#include "board/sim_gpio.hpp"
#include "board/virtual_clock.hpp"
#include "core/timebase.hpp"

namespace icgt::core {
namespace {

constexpr int64_t kUs = 1'000'000;
constexpr int64_t k2023_s = 1'700'000'000;  // 2023-11-14

// A whole-second RTC running off the virtual clock. Its seconds roll over at
// first_rollover_t_us and every second after; a write restarts the prescaler (the next
// rollover is one second after the write), as on the Teensy.
class FakeRtc final : public hal::Rtc {
 public:
  FakeRtc(const sim::VirtualClock& clock, bool valid, int64_t utc_s, uint64_t first_rollover_t_us)
      : clock_(clock), valid_(valid), base_s_(utc_s), next_rollover_t_us_(first_rollover_t_us) {}

  [[nodiscard]] bool get_utc_s(int64_t& utc_s) const override {
    ++reads_;
    if (fail_reads_ || !valid_) return false;
    utc_s = base_s_;
    if (!stopped_ && clock_.now_us() >= next_rollover_t_us_) {
      utc_s += 1 + static_cast<int64_t>((clock_.now_us() - next_rollover_t_us_) / kUs);
    }
    return true;
  }
  [[nodiscard]] bool set_utc_s(int64_t utc_s) override {
    if (fail_writes_) return false;
    writes_.push_back({clock_.now_us(), utc_s});
    valid_ = true;
    base_s_ = utc_s;
    next_rollover_t_us_ = clock_.now_us() + kUs;
    return true;
  }

  struct Write {
    uint64_t t_us;
    int64_t utc_s;
  };
  bool fail_reads_ = false;
  bool fail_writes_ = false;
  bool stopped_ = false;
  std::vector<Write> writes_;
  mutable int reads_ = 0;

 private:
  const sim::VirtualClock& clock_;
  bool valid_;
  int64_t base_s_;
  uint64_t next_rollover_t_us_;
};

// Runs the loop every loop_us until t_end_us (inclusive).
void run_loop(sim::VirtualClock& clock, Timebase& tb, uint64_t t_end_us, uint64_t loop_us) {
  while (clock.now_us() + loop_us <= t_end_us) {
    clock.advance_us(loop_us);
    tb.poll(clock.now_us());
  }
}

TEST(TimebaseRtc, AnchorsAtTheFirstObservedRolloverWithinOneLoopPeriod) {
  sim::VirtualClock clock(5'000);
  FakeRtc rtc(clock, true, k2023_s, 300'123);  // true UTC at device 0: (k2023_s + 1) s - 300'123 us
  Timebase tb(rtc, nullptr);
  tb.begin(clock.now_us());
  EXPECT_EQ(tb.clock_source(), ClockSource::free_running);  // not anchored until the rollover
  EXPECT_TRUE(tb.rtc_set());
  EXPECT_TRUE(tb.rtc_watch_active());

  run_loop(clock, tb, 1'000'000, 1'000);
  ASSERT_EQ(tb.clock_source(), ClockSource::rtc);
  // Observed at the first poll after 300'123 us, i.e. 301'000 us.
  EXPECT_EQ(tb.utc_us_at_boot(), (k2023_s + 1) * kUs - 301'000);
  EXPECT_EQ(tb.rtc_utc_us_at_boot(), tb.utc_us_at_boot());
  EXPECT_EQ(tb.anchor_uncertainty_us(), 1'000u);
  const int64_t true_anchor = (k2023_s + 1) * kUs - 300'123;
  EXPECT_GE(true_anchor - tb.utc_us_at_boot(), 0);
  EXPECT_LE(true_anchor - tb.utc_us_at_boot(), static_cast<int64_t>(tb.anchor_uncertainty_us()));
  EXPECT_FALSE(tb.rtc_watch_active());

  int64_t utc_us = 0;
  ASSERT_TRUE(tb.to_utc_us(2'000'000, utc_us));
  EXPECT_EQ(utc_us, tb.utc_us_at_boot() + 2'000'000);
}

TEST(TimebaseRtc, ReadsTheRtcOncePerPollAndStopsAfterAnchoring) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, true, k2023_s, 10'000);
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  run_loop(clock, tb, 20'000, 1'000);
  const int reads_after_anchor = rtc.reads_;
  EXPECT_EQ(reads_after_anchor, 1 + 10);  // begin + polls at 1..10 ms
  run_loop(clock, tb, 100'000, 1'000);
  EXPECT_EQ(rtc.reads_, reads_after_anchor);
}

TEST(TimebaseRtc, FailedReadsWidenTheUncertaintyWindowFromTheLastGoodRead) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, true, k2023_s, 500'000);
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  run_loop(clock, tb, 490'000, 10'000);
  rtc.fail_reads_ = true;
  run_loop(clock, tb, 530'000, 10'000);  // reads at 500, 510, 520, 530 ms fail
  rtc.fail_reads_ = false;
  run_loop(clock, tb, 540'000, 10'000);
  ASSERT_EQ(tb.clock_source(), ClockSource::rtc);
  EXPECT_EQ(tb.anchor_uncertainty_us(), 50'000u);  // last good read 490 ms, observed at 540 ms
  EXPECT_EQ(tb.utc_us_at_boot(), (k2023_s + 1) * kUs - 540'000);
  EXPECT_EQ(tb.rtc_errors(), 4u);
}

TEST(TimebaseRtc, NeverSetRtcLeavesTheClockFreeRunning) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, false, 0, 0);
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  run_loop(clock, tb, 3'000'000, 1'000);
  EXPECT_EQ(tb.clock_source(), ClockSource::free_running);
  EXPECT_FALSE(tb.rtc_set());
  EXPECT_EQ(tb.utc_us_at_boot(), 0);
  EXPECT_EQ(tb.rtc_utc_us_at_boot(), 0);
  int64_t utc_us = 0;
  EXPECT_FALSE(tb.to_utc_us(1'000, utc_us));
}

TEST(TimebaseRtc, RtcReadingBefore2020CountsAsNeverSet) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, true, 946'684'800, 100'000);  // 2000-01-01, a reset default
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  run_loop(clock, tb, 2'000'000, 1'000);
  EXPECT_FALSE(tb.rtc_set());
  EXPECT_EQ(tb.clock_source(), ClockSource::free_running);
}

TEST(TimebaseRtc, StoppedRtcGivesUpTheWatchAndStaysFreeRunning) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, true, k2023_s, 100'000);
  rtc.stopped_ = true;
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  run_loop(clock, tb, Timebase::kRolloverWaitUs, 1'000);
  EXPECT_TRUE(tb.rtc_watch_active());
  run_loop(clock, tb, Timebase::kRolloverWaitUs + 1'000, 1'000);
  EXPECT_FALSE(tb.rtc_watch_active());
  EXPECT_TRUE(tb.rtc_stalled());
  EXPECT_EQ(tb.clock_source(), ClockSource::free_running);
}

TEST(TimebaseSetTime, AnchorsExactlyToTheHostTimeAtReceptionAndSetsTheRtc) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, false, 0, 0);
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  clock.set_us(7'000'000);
  const int64_t host_utc_us = k2023_s * kUs + 250'000;  // 0.25 s into a second
  ASSERT_EQ(tb.set_time(host_utc_us, 6'999'000), SetTimeResult::ok);  // received 1 ms ago
  EXPECT_EQ(tb.clock_source(), ClockSource::host_set);
  EXPECT_EQ(tb.utc_us_at_boot(), host_utc_us - 6'999'000);
  EXPECT_EQ(tb.anchor_uncertainty_us(), 0u);
  EXPECT_TRUE(tb.rtc_set());
  int64_t utc_us = 0;
  ASSERT_TRUE(tb.to_utc_us(6'999'000, utc_us));
  EXPECT_EQ(utc_us, host_utc_us);
  ASSERT_EQ(rtc.writes_.size(), 1u);
  EXPECT_EQ(rtc.writes_[0].utc_s, k2023_s);
}

TEST(TimebaseSetTime, RewritesTheRtcAtTheNextSecondBoundarySoItsPhaseMatchesUtc) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, false, 0, 0);
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  clock.set_us(1'000'000);
  // UTC k2023_s + 0.25 s at device 1 s: the next whole second is at device 1.75 s.
  ASSERT_EQ(tb.set_time(k2023_s * kUs + 250'000, 1'000'000), SetTimeResult::ok);
  run_loop(clock, tb, 3'000'000, 2'000);
  ASSERT_EQ(rtc.writes_.size(), 2u);
  EXPECT_EQ(rtc.writes_[1].t_us, 1'750'000u);
  EXPECT_EQ(rtc.writes_[1].utc_s, k2023_s + 1);
}

TEST(TimebaseSetTime, TimeBefore2020IsRefusedAndChangesNothing) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, true, k2023_s, 400'000);
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  run_loop(clock, tb, 1'000'000, 1'000);
  ASSERT_EQ(tb.clock_source(), ClockSource::rtc);
  const int64_t anchor_before = tb.utc_us_at_boot();

  EXPECT_EQ(tb.set_time(Timebase::kMinValidUtcUs - 1, clock.now_us()), SetTimeResult::invalid_time);
  EXPECT_EQ(tb.set_time(0, clock.now_us()), SetTimeResult::invalid_time);
  EXPECT_EQ(tb.set_time(-5, clock.now_us()), SetTimeResult::invalid_time);
  EXPECT_EQ(tb.clock_source(), ClockSource::rtc);
  EXPECT_EQ(tb.utc_us_at_boot(), anchor_before);
  EXPECT_TRUE(rtc.writes_.empty());

  EXPECT_EQ(tb.set_time(Timebase::kMinValidUtcUs, clock.now_us()), SetTimeResult::ok);  // 2020-01-01 itself
  EXPECT_EQ(tb.clock_source(), ClockSource::host_set);
}

TEST(TimebaseSetTime, RtcWriteFailureIsRefusedInternalAndChangesNothing) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, false, 0, 0);
  rtc.fail_writes_ = true;
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  EXPECT_EQ(tb.set_time(k2023_s * kUs, 0), SetTimeResult::internal);
  EXPECT_EQ(tb.clock_source(), ClockSource::free_running);
  EXPECT_FALSE(tb.rtc_set());
  EXPECT_EQ(tb.utc_us_at_boot(), 0);
}

TEST(TimebaseSetTime, HostTimeOverridesARolloverWatchStillInProgress) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, true, k2023_s, 900'000);
  Timebase tb(rtc, nullptr);
  tb.begin(0);
  run_loop(clock, tb, 100'000, 1'000);
  ASSERT_EQ(tb.set_time((k2023_s + 100) * kUs, clock.now_us()), SetTimeResult::ok);
  EXPECT_FALSE(tb.rtc_watch_active());
  run_loop(clock, tb, 3'000'000, 1'000);
  EXPECT_EQ(tb.clock_source(), ClockSource::host_set);
  EXPECT_EQ(tb.utc_us_at_boot(), (k2023_s + 100) * kUs - 100'000);
}

class TimebasePps : public ::testing::Test {
 protected:
  void SetUp() override {
    tb.begin(0);
    run_loop(clock, tb, 1'000'000, 1'000);  // anchored to the RTC
    ASSERT_EQ(tb.clock_source(), ClockSource::rtc);
    ASSERT_TRUE(tb.start_pps(true));
  }

  // A rising and a falling edge (100 ms pulse) at t_us; the loop then drains.
  void pulse_at(uint64_t t_us) {
    clock.set_us(t_us);
    line.fire(true, t_us);
    clock.set_us(t_us + 100'000);
    line.fire(false, t_us + 100'000);
    drain();
    tb.poll(clock.now_us());
  }
  void drain() {
    PpsEdge e;
    while (tb.pop_pps(e)) edges.push_back(e);
  }

  sim::VirtualClock clock{0};
  FakeRtc rtc{clock, true, k2023_s, 500'000};
  sim::SimEdgeInput line;
  Timebase tb{rtc, &line};
  std::vector<PpsEdge> edges;
};

TEST_F(TimebasePps, QueuesEachActiveEdgeWithItsTimeAndCount) {
  pulse_at(2'000'000);
  pulse_at(3'000'100);
  ASSERT_EQ(edges.size(), 2u);  // falling edges are not PPS
  EXPECT_EQ(edges[0].t_us, 2'000'000u);
  EXPECT_EQ(edges[0].count, 1u);
  EXPECT_EQ(edges[1].t_us, 3'000'100u);
  EXPECT_EQ(edges[1].count, 2u);
  EXPECT_EQ(tb.pps_edges(), 2u);
}

TEST_F(TimebasePps, LocksAfterThreeEdgesOneSecondApartWithin500Us) {
  pulse_at(2'000'000);
  pulse_at(3'000'400);  // +1 s + 400 us
  EXPECT_FALSE(tb.pps_locked());
  EXPECT_EQ(tb.clock_source(), ClockSource::rtc);
  pulse_at(4'000'000);  // +1 s - 400 us
  EXPECT_TRUE(tb.pps_locked());
  EXPECT_EQ(tb.clock_source(), ClockSource::rtc_and_pps);
}

TEST_F(TimebasePps, EdgeOutsideToleranceRestartsTheRun) {
  pulse_at(2'000'000);
  pulse_at(3'000'000);
  pulse_at(4'000'501);  // 501 us late
  EXPECT_FALSE(tb.pps_locked());
  pulse_at(5'000'501);
  EXPECT_FALSE(tb.pps_locked());
  pulse_at(6'000'501);
  EXPECT_TRUE(tb.pps_locked());
}

TEST_F(TimebasePps, MissingPulseDropsTheLockOnceItIsOverdue) {
  for (uint64_t s = 2; s <= 4; ++s) pulse_at(s * 1'000'000);
  ASSERT_TRUE(tb.pps_locked());
  clock.set_us(5'000'500);
  tb.poll(clock.now_us());
  EXPECT_TRUE(tb.pps_locked());  // the 5 s pulse may still come (tolerance)
  clock.set_us(5'000'501);
  tb.poll(clock.now_us());
  EXPECT_FALSE(tb.pps_locked());
  EXPECT_EQ(tb.clock_source(), ClockSource::rtc);
}

TEST_F(TimebasePps, QueuedButUnreadEdgeIsNotTakenForAMissingPulse) {
  for (uint64_t s = 2; s <= 4; ++s) pulse_at(s * 1'000'000);
  clock.set_us(5'000'000);
  line.fire(true, 5'000'000);  // arrives, but the loop is late to drain it
  clock.set_us(7'000'000);
  tb.poll(clock.now_us());
  EXPECT_TRUE(tb.pps_locked());
  drain();
  EXPECT_TRUE(tb.pps_locked());
}

TEST_F(TimebasePps, FallingPolarityCountsFallingEdges) {
  tb.set_pps_rising(false);
  pulse_at(2'000'000);  // rising at 2 s, falling at 2.1 s
  ASSERT_EQ(edges.size(), 1u);
  EXPECT_EQ(edges[0].t_us, 2'100'000u);
}

TEST_F(TimebasePps, FullQueueCountsDropsAndTheCountShowsTheGap) {
  for (uint64_t i = 0; i < kPpsQueueCapacity + 3; ++i) line.fire(true, 2'000'000 + i * 1'000'000);
  EXPECT_EQ(tb.pps_queue().dropped(), 3u);
  drain();
  ASSERT_EQ(edges.size(), kPpsQueueCapacity);
  line.fire(true, 20'000'000);
  drain();
  EXPECT_EQ(edges.back().count, kPpsQueueCapacity + 4);  // 3 counted but never queued
}

TEST(TimebasePpsLine, MissingOrUnwiredLineCannotStartPps) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, false, 0, 0);
  Timebase no_line(rtc, nullptr);
  EXPECT_FALSE(no_line.start_pps(true));
  sim::SimEdgeInput unwired;
  unwired.set_wired(false);
  Timebase tb(rtc, &unwired);
  EXPECT_FALSE(tb.start_pps(true));
}

TEST(TimebasePpsLine, PpsLockWithoutAnyUtcAnchorStillReportsFreeRunning) {
  sim::VirtualClock clock(0);
  FakeRtc rtc(clock, false, 0, 0);
  sim::SimEdgeInput line;
  Timebase tb(rtc, &line);
  tb.begin(0);
  ASSERT_TRUE(tb.start_pps(true));
  for (uint64_t s = 1; s <= 3; ++s) line.fire(true, s * 1'000'000);
  PpsEdge e;
  while (tb.pop_pps(e)) {
  }
  EXPECT_TRUE(tb.pps_locked());
  EXPECT_EQ(tb.clock_source(), ClockSource::free_running);
}

}  // namespace
}  // namespace icgt::core
