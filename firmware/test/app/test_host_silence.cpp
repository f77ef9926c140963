// A capture whose host went silent stops by itself after START_CAPTURE.host_timeout_ms (issue 30): the
// rule on its own (HostWatchdog) and in the application, with the silence just under and over the timeout,
// the rule turned off, a host that comes back in time, a stop while already stopped, and the device's
// account of it (DEVICE_STATE.stop_cause) when a host comes back.
#include <gtest/gtest.h>

#include <string>

#include "app/app_rig.hpp"
#include "core/host_watchdog.hpp"

namespace icgt {
namespace {

using core::HostWatchdog;
using proto::ErrorCode;
using test::Rig;

constexpr uint32_t kTimeoutMs = 5'000;
constexpr uint64_t kTimeoutUs = uint64_t{kTimeoutMs} * 1000;

TEST(HostWatchdog, ExpiresAtTheTimeoutNotBeforeAndOnlyOnce) {
  HostWatchdog w;
  w.arm(kTimeoutMs, 1'000'000);
  EXPECT_FALSE(w.expired(1'000'000 + kTimeoutUs - 1)) << "one microsecond under the timeout";
  EXPECT_TRUE(w.expired(1'000'000 + kTimeoutUs));
  EXPECT_FALSE(w.armed());
  EXPECT_FALSE(w.expired(1'000'000 + 10 * kTimeoutUs)) << "says so once per capture";
}

TEST(HostWatchdog, EachFrameFromTheHostStartsTheSilenceAgain) {
  HostWatchdog w;
  w.arm(kTimeoutMs, 0);
  for (uint64_t t = 4'000'000; t <= 40'000'000; t += 4'000'000) {
    EXPECT_FALSE(w.expired(t)) << t;
    w.heard(t);
  }
  EXPECT_EQ(w.heard_t_us(), 40'000'000u);
  EXPECT_TRUE(w.expired(40'000'000 + kTimeoutUs));
}

TEST(HostWatchdog, ZeroNeverExpiresAndDisarmStopsIt) {
  HostWatchdog off;
  off.arm(0, 0);
  EXPECT_FALSE(off.armed());
  EXPECT_FALSE(off.expired(UINT64_MAX / 2));
  HostWatchdog w;
  w.arm(kTimeoutMs, 0);
  w.disarm();
  EXPECT_FALSE(w.expired(10 * kTimeoutUs));
}

TEST(HostWatchdog, TimeoutsOutsideTheLimitsAreInvalid) {
  EXPECT_TRUE(HostWatchdog::valid(0));
  EXPECT_TRUE(HostWatchdog::valid(HostWatchdog::kMinTimeoutMs));
  EXPECT_TRUE(HostWatchdog::valid(HostWatchdog::kMaxTimeoutMs));
  EXPECT_FALSE(HostWatchdog::valid(HostWatchdog::kMinTimeoutMs - 1));
  EXPECT_FALSE(HostWatchdog::valid(HostWatchdog::kMaxTimeoutMs + 1));
}

// The application, sensors off (only the trigger and the link matter here, and the run stays short).
struct SilenceRig : Rig {
  SilenceRig() {
    proto::Configure c = test::default_configure();
    c.imu_rate_hz = 0;
    c.range_rate_hz = 0;
    const uint32_t seq = host.send(c);
    run_for(50'000);
    EXPECT_EQ(host.ack_for(seq).error_code, 0u);
  }
  // An interval capture at 5 fps with this host timeout; returns the device time it was accepted at.
  uint64_t start(uint32_t timeout_ms) {
    proto::StartCapture s = test::interval_capture();
    s.host_timeout_ms = timeout_ms;
    const uint32_t seq = host.send(s);
    const uint64_t t = board.clock().now_us();
    run_for(10'000);
    EXPECT_EQ(host.ack_for(seq).error_code, 0u);
    return t;
  }
  void keep_alive() {
    proto::HostReceived r;
    r.next_seq = 0;
    r.recording_id = 7;
    (void)host.send(r);
  }
  proto::DeviceState ask_state() {
    proto::Ping p;
    p.nonce = 0;  // a fresh HELLO and DEVICE_STATE
    (void)host.send(p);
    run_for(10'000);
    const auto states = host.of(proto::MsgId::DEVICE_STATE);
    EXPECT_FALSE(states.empty());
    return states.empty() ? proto::DeviceState{} : states.back().as<proto::DeviceState>();
  }
  core::CaptureState state() { return board.app().trigger().state(); }
  uint32_t fired() { return board.app().trigger().triggers_fired(); }
  std::size_t logs_containing(const std::string& text) {
    std::size_t n = 0;
    for (const auto& f : host.of(proto::MsgId::LOG)) {
      const auto m = f.as<proto::Log>();
      if (std::string(m.text, m.text_len).find(text) != std::string::npos) ++n;
    }
    return n;
  }
};

TEST(AppHostSilence, CaptureRunsJustUnderTheTimeoutAndStopsJustOverIt) {
  SilenceRig rig;
  const uint64_t t0 = rig.start(kTimeoutMs);
  rig.run_for(t0 + kTimeoutUs - 20'000 - rig.board.clock().now_us());
  EXPECT_EQ(rig.state(), core::CaptureState::capturing) << "20 ms under the timeout";
  rig.run_for(40'000);
  EXPECT_NE(rig.state(), core::CaptureState::capturing) << "20 ms over it";
  const uint32_t fired = rig.fired();
  EXPECT_NEAR(fired, 25u, 1u) << "5 s at 5 fps";
  rig.run_for(3'000'000);
  EXPECT_EQ(rig.fired(), fired) << "the camera shoots no more";
  EXPECT_EQ(rig.logs_containing("capture stopped by the device: no frame from the host for ms 5000"), 1u);

  const proto::DeviceState d = rig.ask_state();
  EXPECT_EQ(d.stop_cause, static_cast<uint8_t>(proto::StopCause::host_silent));
  EXPECT_EQ(d.host_timeout_ms, kTimeoutMs);
  EXPECT_GE(d.stopped_t_us, t0 + kTimeoutUs);
  EXPECT_LT(d.stopped_t_us, t0 + kTimeoutUs + 20'000);
}

TEST(AppHostSilence, AHostThatComesBackBeforeTheTimeoutKeepsTheCaptureRunning) {
  SilenceRig rig;
  (void)rig.start(kTimeoutMs);
  for (int i = 0; i < 6; ++i) {  // 24 s, a frame every 4 s: never 5 s of silence
    rig.run_for(4'000'000);
    rig.keep_alive();
  }
  EXPECT_EQ(rig.state(), core::CaptureState::capturing);
  const proto::DeviceState d = rig.ask_state();
  EXPECT_EQ(d.stop_cause, static_cast<uint8_t>(proto::StopCause::none));
  EXPECT_EQ(d.stopped_t_us, 0u);
  EXPECT_EQ(d.recording_id, 7u) << "HOST_RECEIVED's recording, given back";
}

TEST(AppHostSilence, ZeroTurnsTheRuleOffAndTheCameraGoesOn) {
  SilenceRig rig;
  (void)rig.start(0);
  rig.run_for(4 * kTimeoutUs);
  EXPECT_EQ(rig.state(), core::CaptureState::capturing);
  EXPECT_NEAR(rig.fired(), 100u, 1u);
  EXPECT_EQ(rig.logs_containing("stopped by the device"), 0u);
}

TEST(AppHostSilence, AStopWhileAlreadyStoppedIsRefusedAndChangesNothing) {
  SilenceRig rig;
  (void)rig.start(kTimeoutMs);
  rig.run_for(kTimeoutUs + 100'000);
  ASSERT_NE(rig.state(), core::CaptureState::capturing);
  const uint64_t stopped = rig.board.app().stopped_t_us();
  proto::StopCapture stop;
  const uint32_t seq = rig.host.send(stop);  // the host back, stopping what already stopped
  rig.run_for(10'000);
  EXPECT_EQ(rig.host.ack_for(seq).error_code, static_cast<uint8_t>(ErrorCode::not_capturing));
  EXPECT_EQ(rig.board.app().stop_cause(), proto::StopCause::host_silent) << "the device's account stays";
  EXPECT_EQ(rig.board.app().stopped_t_us(), stopped);

  // Stopped by the host, then silent for longer than the timeout: nothing more to stop, nothing said.
  (void)rig.start(kTimeoutMs);
  const uint32_t stop_seq = rig.host.send(stop);
  rig.run_for(10'000);
  EXPECT_EQ(rig.host.ack_for(stop_seq).error_code, 0u);
  rig.run_for(2 * kTimeoutUs);
  EXPECT_EQ(rig.board.app().stop_cause(), proto::StopCause::host);
  EXPECT_EQ(rig.logs_containing("stopped by the device"), 1u) << "only the first capture's";
}

TEST(AppHostSilence, ACountCaptureThatRanOutIsDoneNotSilenced) {
  SilenceRig rig;
  proto::StartCapture s = test::interval_capture();
  s.mode = static_cast<uint8_t>(proto::CaptureMode::count);
  s.count = 3;
  s.host_timeout_ms = kTimeoutMs;
  (void)rig.host.send(s);
  rig.run_for(2 * kTimeoutUs);
  EXPECT_EQ(rig.fired(), 3u);
  EXPECT_EQ(rig.board.app().stop_cause(), proto::StopCause::done);
  EXPECT_EQ(rig.logs_containing("stopped by the device"), 0u);
}

TEST(AppHostSilence, AnUnpluggedCableStopsTheCaptureAndTheDeviceSaysSoWhenItIsBack) {
  SilenceRig rig;
  const uint64_t t0 = rig.start(kTimeoutMs);
  rig.keep_alive();
  rig.run_for(1'000'000);
  rig.link.set_connected(false);
  rig.run_for(kTimeoutUs + 1'000'000);
  EXPECT_NE(rig.state(), core::CaptureState::capturing);
  rig.link.set_connected(true);
  rig.run_for(core::App::kLinkSettleUs + 20'000);
  const auto states = rig.host.of(proto::MsgId::DEVICE_STATE);
  ASSERT_GE(states.size(), 2u) << "one at boot, one when the host came back";
  const auto d = states.back().as<proto::DeviceState>();
  EXPECT_EQ(d.stop_cause, static_cast<uint8_t>(proto::StopCause::host_silent));
  // Silence counts from the host's last frame (just after the start), not from the unplug.
  EXPECT_GE(d.stopped_t_us, t0 + kTimeoutUs);
  EXPECT_LT(d.stopped_t_us, t0 + kTimeoutUs + 40'000);
  EXPECT_EQ(d.recording_id, 7u);
}

TEST(AppHostSilence, ATimeoutOutsideItsLimitsIsRefusedNamingIt) {
  SilenceRig rig;
  for (uint32_t bad : {HostWatchdog::kMinTimeoutMs - 1, HostWatchdog::kMaxTimeoutMs + 1}) {
    proto::StartCapture s = test::interval_capture();
    s.host_timeout_ms = bad;
    const uint32_t seq = rig.host.send(s);
    rig.run_for(10'000);
    const proto::Ack a = rig.host.ack_for(seq);
    EXPECT_EQ(a.error_code, static_cast<uint8_t>(ErrorCode::out_of_range)) << bad;
    EXPECT_EQ(a.detail, static_cast<uint32_t>(proto::Limit::host_timeout)) << bad;
    EXPECT_EQ(rig.state(), core::CaptureState::idle);
  }
}

}  // namespace
}  // namespace icgt
