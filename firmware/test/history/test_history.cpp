// The history ring and RESEND: unit tests of core::History against a model of what was
// recorded (random streams and requests), and the App answering RESEND on the simulated board
// after unplugs, inside and beyond the ring.
#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <vector>

#include "board/sim_board.hpp"
#include "core/history.hpp"
#include "frame.hpp"

namespace icgt {
namespace {

using core::FrameKind;
using core::History;

uint8_t type_for(FrameKind k, std::mt19937& rng) {
  switch (k) {
    case FrameKind::exposure: return static_cast<uint8_t>(proto::MsgId::EXPOSURE);
    case FrameKind::pps: return static_cast<uint8_t>(proto::MsgId::PPS);
    case FrameKind::sample:
      return static_cast<uint8_t>(rng() % 3 == 0 ? proto::MsgId::IMU : proto::MsgId::RANGE);
    case FrameKind::other: return static_cast<uint8_t>(proto::MsgId::STATUS);
  }
  return 0;
}

struct Recorded {
  uint8_t type;
  uint8_t first_byte;
};

// The model: which seqs each ring still holds is the last `capacity` of its kind.
std::set<uint32_t> kept_by_model(const std::map<uint32_t, Recorded>& all) {
  std::vector<uint32_t> ev, imu, rng;
  for (const auto& [seq, r] : all) {
    const auto id = static_cast<proto::MsgId>(r.type);
    if (id == proto::MsgId::EXPOSURE || id == proto::MsgId::PPS) ev.push_back(seq);
    if (id == proto::MsgId::IMU) imu.push_back(seq);
    if (id == proto::MsgId::RANGE) rng.push_back(seq);
  }
  std::set<uint32_t> kept;
  auto keep_last = [&](const std::vector<uint32_t>& v, std::size_t cap) {
    for (std::size_t i = v.size() > cap ? v.size() - cap : 0; i < v.size(); ++i) kept.insert(v[i]);
  };
  keep_last(ev, History::kSizes.event_slots);
  keep_last(imu, History::kSizes.imu_slots);
  keep_last(rng, History::kSizes.range_slots);
  return kept;
}

TEST(History, KeepsTheNewestOfEachKindAndKnowsEveryRecentKind) {
  // Property test: random mixes of kinds (more samples than events, as in flight), random
  // lookups; what History returns must be exactly the model's.
  for (uint32_t trial = 0; trial < 6; ++trial) {
    std::mt19937 rng(1234 + trial);
    auto h = std::make_unique<History>();
    std::map<uint32_t, Recorded> all;
    const uint32_t n = 20'000 + rng() % 30'000;
    for (uint32_t seq = 0; seq < n; ++seq) {
      const uint32_t r = rng() % 100;
      const FrameKind k = r < 2 ? FrameKind::exposure : r < 3 ? FrameKind::pps : r < 8 ? FrameKind::other
                                                                                      : FrameKind::sample;
      const uint8_t type = type_for(k, rng);
      uint8_t body[proto::Imu::kMaxBodyBytes]{};
      body[0] = static_cast<uint8_t>(seq);
      const std::size_t len = type == static_cast<uint8_t>(proto::MsgId::IMU) ? proto::Imu::kMaxBodyBytes : 12;
      h->record(seq, type, body, len);
      all[seq] = {type, body[0]};
    }
    const std::set<uint32_t> kept = kept_by_model(all);
    for (int q = 0; q < 300; ++q) {
      const uint32_t from = rng() % (n + 100);
      const uint32_t end = from + 1 + rng() % 5000;
      const auto it = kept.lower_bound(from);
      const bool expect = it != kept.end() && *it < end;
      core::HistoryEntry e;
      ASSERT_EQ(h->next_kept(from, end, e), expect) << "from " << from << " end " << end;
      if (expect) {
        EXPECT_EQ(e.seq, *it);
        EXPECT_EQ(e.type, all[*it].type);
        EXPECT_EQ(e.body[0], all[*it].first_byte);
      }
      FrameKind k;
      const bool known = h->kind(from, k);
      EXPECT_EQ(known, from < n) << from;  // n < kind_entries: every recorded seq is known
      if (known) {
        EXPECT_EQ(k, core::kind_of_type(all[from].type));
      }
    }
  }
}

TEST(History, SequenceNumbersWrapAround) {
  auto h = std::make_unique<History>();
  const uint8_t body[proto::Exposure::kMaxBodyBytes]{};
  const uint32_t start = 0xFFFFFF00u;
  for (uint32_t i = 0; i < 512; ++i) {
    h->record(start + i, static_cast<uint8_t>(proto::MsgId::EXPOSURE), body, sizeof body);
  }
  core::HistoryEntry e;
  ASSERT_TRUE(h->next_kept(0xFFFFFFF0u, 0x10u, e));
  EXPECT_EQ(e.seq, 0xFFFFFFF0u);
  ASSERT_TRUE(h->next_kept(0x5u, 0x10u, e));
  EXPECT_EQ(e.seq, 0x5u);
  FrameKind k;
  EXPECT_TRUE(h->kind(0x3u, k));
  EXPECT_FALSE(h->kind(0x100u, k)) << "not sent yet";
}

TEST(History, ForgetsKindsBeyondItsKindRing) {
  auto h = std::make_unique<History>();
  const uint8_t body[16]{};
  const uint32_t n = static_cast<uint32_t>(History::kSizes.kind_entries) + 10;
  for (uint32_t s = 0; s < n; ++s) h->record(s, static_cast<uint8_t>(proto::MsgId::RANGE), body, 12);
  FrameKind k;
  EXPECT_FALSE(h->kind(9, k));
  EXPECT_TRUE(h->kind(10, k));
  EXPECT_EQ(h->first_known_seq(), 10u);
}

TEST(History, BoardSizesAreWhatTheDocsSay) {
  // 10 min of 5 fps exposures with PPS on the Teensy 4.1; the 3.6 keeps less (its RAM is 256 KiB).
  EXPECT_GE(core::kTeensy41History.event_slots, 3600u);
  EXPECT_LT(core::kTeensy36History.event_slots, core::kTeensy41History.event_slots);
  EXPECT_GT(core::kTeensy41History.event_slots / 6, core::kTeensy41History.imu_slots / 100)
      << "events reach further back in time than samples";
}

// ------------------------------------------------------------------ the App answering RESEND

struct RxFrame {
  uint8_t type;
  uint8_t flags;
  uint32_t seq;
  std::vector<uint8_t> body;
  template <class Msg>
  Msg as() const {
    Msg m;
    EXPECT_TRUE(m.decode(body.data(), body.size()));
    return m;
  }
};

struct ResendRig {
  ResendRig() : board(sim::SimBoardConfig{}, link) {
    board.begin();
    run_for(core::App::kLinkSettleUs);
  }
  template <class Msg>
  uint32_t send(const Msg& msg) {
    uint8_t wire[proto::kMaxWireBytes];
    const std::size_t n = proto::encode_message(msg, seq++, 0, wire, sizeof wire);
    EXPECT_GT(n, 0u);
    link.host_send(wire, n);
    return seq - 1;
  }
  void run_for(uint64_t dt_us) {
    const uint64_t end = board.clock().now_us() + dt_us;
    while (board.clock().now_us() < end) {
      board.run_until(std::min(end, board.clock().now_us() + 10'000));
      for (uint8_t b : link.host_take()) {
        if (dec.push(b) == proto::StreamDecoder::Status::frame) {
          frames.push_back({dec.header().type, dec.header().flags, dec.header().seq,
                            std::vector<uint8_t>(dec.body(), dec.body() + dec.body_len())});
        }
      }
    }
  }
  // Live frames' sequence numbers, and the gaps between them.
  std::vector<std::pair<uint32_t, uint32_t>> gaps() const {
    std::vector<std::pair<uint32_t, uint32_t>> out;
    bool first = true;
    uint32_t expect = 0;
    for (const auto& f : frames) {
      if (f.flags & proto::FrameFlags::retransmit) continue;
      if (!first && f.seq != expect) out.emplace_back(expect, f.seq);
      first = false;
      expect = f.seq + 1;
    }
    return out;
  }
  std::set<uint32_t> image_indices() const {
    std::set<uint32_t> out;
    for (const auto& f : frames) {
      if (f.type == static_cast<uint8_t>(proto::MsgId::EXPOSURE)) out.insert(f.as<proto::Exposure>().image_index);
    }
    return out;
  }
  std::vector<RxFrame> of(proto::MsgId id) const {
    std::vector<RxFrame> out;
    for (const auto& f : frames) {
      if (f.type == static_cast<uint8_t>(id)) out.push_back(f);
    }
    return out;
  }
  // RESEND for every gap (in pieces of at most 65535), then run until the answers are in.
  std::vector<proto::ResendLost> resend_all() {
    for (const auto& [a, b] : gaps()) {
      for (uint32_t s = a; s != b;) {
        const uint32_t n = std::min<uint32_t>(b - s, 0xFFFF);
        proto::Resend r;
        r.first_seq = s;
        r.count = static_cast<uint16_t>(n);
        send(r);
        ++requests_sent;
        s += n;
      }
    }
    run_for(3'000'000);
    std::vector<proto::ResendLost> out;
    for (const auto& f : of(proto::MsgId::RESEND_LOST)) out.push_back(f.as<proto::ResendLost>());
    return out;
  }
  sim::MemoryStream link{1 << 16};
  sim::SimBoard board;
  proto::StreamDecoder dec;
  std::vector<RxFrame> frames;
  uint32_t seq = 0;
  std::size_t requests_sent = 0;
};

proto::StartCapture five_fps() {
  proto::StartCapture s;
  s.mode = static_cast<uint8_t>(proto::CaptureMode::interval);
  s.interval_us = 200'000;
  s.shutter_pulse_us = 20'000;
  return s;
}

TEST(AppResend, ThirtySecondUnplugLosesNoExposure) {
  ResendRig rig;
  rig.run_for(1'000'000);
  rig.send(five_fps());
  rig.run_for(2'000'000);
  rig.link.set_connected(false);
  rig.run_for(30'000'000);
  rig.link.set_connected(true);
  rig.run_for(2'000'000);
  ASSERT_FALSE(rig.gaps().empty()) << "the unplug must show as a gap";
  const std::size_t exposures_live = rig.of(proto::MsgId::EXPOSURE).size();
  const auto answers = rig.resend_all();
  ASSERT_GT(rig.requests_sent, 0u);
  ASSERT_EQ(answers.size(), rig.requests_sent) << "one RESEND_LOST per RESEND";
  uint32_t lost_exposures = 0, resent = 0, lost_samples = 0;
  for (const auto& a : answers) {
    lost_exposures += a.exposures;
    resent += a.resent;
    lost_samples += a.samples;
    EXPECT_EQ(a.resent + a.exposures + a.pps + a.samples + a.other + a.unknown, a.count);
  }
  EXPECT_EQ(lost_exposures, 0u);
  EXPECT_GT(lost_samples, 0u) << "30 s of samples exceed the sample rings";
  std::size_t retransmitted = 0;
  for (const auto& f : rig.frames) retransmitted += (f.flags & proto::FrameFlags::retransmit) ? 1 : 0;
  EXPECT_EQ(retransmitted, resent);
  EXPECT_GT(rig.of(proto::MsgId::EXPOSURE).size(), exposures_live + 140) << "~150 exposures came back";
  // Every exposure the camera made is there, once per image index.
  const auto truth = rig.board.camera().exposures().size();
  EXPECT_EQ(rig.image_indices().size(), truth);
  const auto st = rig.of(proto::MsgId::STATUS).back().as<proto::Status>();
  EXPECT_EQ(st.dropped_event, 0u);
}

TEST(AppResend, BeyondTheRingTheLossIsCountedExactly) {
  ResendRig rig;
  rig.run_for(1'000'000);
  proto::StartCapture fast = five_fps();
  fast.interval_us = 50'000;  // 20 fps + PPS: the event ring's reach is shorter
  fast.shutter_pulse_us = 5'000;
  proto::Configure c;
  c.imu_rate_hz = 100;
  c.imu_mode = 0x0C;
  c.range_rate_hz = 200;
  c.lidar_model = static_cast<uint8_t>(proto::LidarModel::v3);
  c.lidar_bias_every = 100;
  c.polarity = proto::PinPolarity::focus_active_high | proto::PinPolarity::shutter_active_high;
  c.feedback_enabled = 0;  // one EXPOSURE per trigger, whatever the camera does at 20 fps
  c.feedback_timeout_us = 30'000;
  rig.send(c);
  rig.run_for(200'000);
  rig.send(fast);
  rig.run_for(1'000'000);
  rig.link.set_connected(false);
  const uint64_t outage_us =
      static_cast<uint64_t>(History::kSizes.event_slots) * 1'000'000 / 20 + 20'000'000;  // 20 s more
  rig.run_for(outage_us);
  rig.link.set_connected(true);
  rig.run_for(1'000'000);
  const auto answers = rig.resend_all();
  uint32_t lost = 0;
  for (const auto& a : answers) lost += a.exposures;
  const auto st = rig.of(proto::MsgId::STATUS).back().as<proto::Status>();
  std::set<uint32_t> indices;  // EXPOSURE frames received, live or resent, once each
  for (const auto& f : rig.of(proto::MsgId::EXPOSURE)) {
    const auto e = f.as<proto::Exposure>();
    if (e.trigger_t_us <= st.t_us) indices.insert(e.image_index);
  }
  const std::size_t truth = st.triggers_fired;  // the device's own count, at its last STATUS
  const std::size_t got = indices.size();
  EXPECT_GT(lost, 300u);
  EXPECT_EQ(got + lost, truth) << "every exposure is either back or counted as lost";
}

TEST(AppResend, AnswersAskAgainAndOutOfRangeRequests) {
  ResendRig rig;
  rig.run_for(2'000'000);
  proto::Resend none;
  const uint32_t s0 = rig.send(none);
  proto::Resend future;
  future.first_seq = 1'000'000;
  future.count = 10;
  const uint32_t s1 = rig.send(future);
  rig.run_for(200'000);
  std::map<uint32_t, proto::Ack> acks;
  for (const auto& f : rig.of(proto::MsgId::ACK)) {
    const auto a = f.as<proto::Ack>();
    acks[a.request_seq] = a;
  }
  EXPECT_EQ(acks[s0].error_code, static_cast<uint8_t>(proto::ErrorCode::out_of_range));
  EXPECT_EQ(acks[s1].error_code, static_cast<uint8_t>(proto::ErrorCode::ok));
  const auto lost = rig.of(proto::MsgId::RESEND_LOST);
  ASSERT_EQ(lost.size(), 1u);
  EXPECT_EQ(lost[0].as<proto::ResendLost>().unknown, 10u) << "not sent yet: unknown";
}

TEST(AppResend, DeviceStateFollowsHelloAndReportsHostReceived) {
  ResendRig rig;
  rig.run_for(1'000'000);
  rig.send(five_fps());
  proto::HostReceived hr;
  hr.next_seq = 42;
  rig.send(hr);
  rig.run_for(500'000);
  proto::Ping ping;
  ping.nonce = 0;
  rig.send(ping);
  rig.run_for(300'000);
  const auto states = rig.of(proto::MsgId::DEVICE_STATE);
  ASSERT_EQ(states.size(), 2u) << "one after the boot HELLO, one after PING 0";
  const auto d = states.back().as<proto::DeviceState>();
  EXPECT_EQ(d.capture_state, static_cast<uint8_t>(proto::CaptureState::capturing));
  EXPECT_EQ(d.interval_us, 200'000u);
  EXPECT_EQ(d.host_received_seq, 42u);
  EXPECT_EQ(d.host_received_valid, 1u);
  EXPECT_EQ(d.imu_rate_hz, 100u);
  EXPECT_GT(d.capture_start_seq, 0u);
  EXPECT_LE(d.capture_start_seq, d.next_seq);
}

}  // namespace
}  // namespace icgt
