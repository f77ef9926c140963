// The device application behind its simulated board, driven like a host would: the test rig shared by
// the App tests (test_app.cpp, test_host_silence.cpp).
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <vector>

#include "board/sim_board.hpp"
#include "frame.hpp"

namespace icgt::test {

struct Frame {
  uint8_t type;
  uint32_t seq;
  std::vector<uint8_t> body;

  template <class Msg>
  Msg as() const {
    Msg m;
    EXPECT_TRUE(m.decode(body.data(), body.size()));
    return m;
  }
};

class Host {
 public:
  explicit Host(sim::MemoryStream& link) : link_(link) {}

  template <class Msg>
  uint32_t send(const Msg& msg) {
    uint8_t wire[proto::kMaxWireBytes];
    const std::size_t n = proto::encode_message(msg, seq_, 0, wire, sizeof wire);
    EXPECT_GT(n, 0u);
    link_.host_send(wire, n);
    return seq_++;
  }

  // Decodes everything the device sent since the last call.
  void collect() {
    for (uint8_t b : link_.host_take()) {
      if (dec_.push(b) == proto::StreamDecoder::Status::frame) {
        frames_.push_back({dec_.header().type, dec_.header().seq,
                           std::vector<uint8_t>(dec_.body(), dec_.body() + dec_.body_len())});
      }
    }
  }

  std::vector<Frame> of(proto::MsgId id) const {
    std::vector<Frame> out;
    for (const auto& f : frames_) {
      if (f.type == static_cast<uint8_t>(id)) out.push_back(f);
    }
    return out;
  }

  proto::Ack ack_for(uint32_t seq) const {
    for (const auto& f : of(proto::MsgId::ACK)) {
      const auto a = f.as<proto::Ack>();
      if (a.request_seq == seq) return a;
    }
    ADD_FAILURE() << "no ACK for host seq " << seq;
    return {};
  }

  const proto::DecoderStats& stats() const { return dec_.stats(); }
  std::vector<Frame>& frames() { return frames_; }

 private:
  sim::MemoryStream& link_;
  proto::StreamDecoder dec_;
  std::vector<Frame> frames_;
  uint32_t seq_ = 0;
};

inline proto::StartCapture interval_capture(uint32_t interval_us = 200'000, uint32_t pulse_us = 20'000) {
  proto::StartCapture s;
  s.mode = static_cast<uint8_t>(proto::CaptureMode::interval);
  s.interval_us = interval_us;
  s.shutter_pulse_us = pulse_us;
  return s;
}

inline proto::Configure default_configure() {
  proto::Configure c;
  c.imu_rate_hz = 100;
  c.imu_mode = 0x0C;
  c.range_rate_hz = 500;
  c.lidar_model = static_cast<uint8_t>(proto::LidarModel::v3);
  c.lidar_bias_every = 100;
  c.polarity = proto::PinPolarity::focus_active_high | proto::PinPolarity::shutter_active_high;
  c.feedback_enabled = 1;
  c.feedback_timeout_us = 150'000;
  return c;
}

struct Rig {
  explicit Rig(sim::SimBoardConfig cfg = {}) : board(cfg, link), host(link) {
    board.begin();
    run_for(core::App::kLinkSettleUs);  // the device holds its output while a host opens the port
  }
  void run_for(uint64_t dt_us) {
    const uint64_t end = board.clock().now_us() + dt_us;
    while (board.clock().now_us() < end) {
      board.run_until(std::min(end, board.clock().now_us() + 10'000));
      host.collect();
    }
  }
  sim::MemoryStream link;
  sim::SimBoard board;
  Host host;
};

}  // namespace icgt::test
