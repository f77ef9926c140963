// Framing: CRC-32, COBS, frame encoder and stream decoder (SPEC.md §1-§7).
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <random>
#include <vector>

#include "crc32.hpp"
#include "frame.hpp"

namespace icgt::proto {
namespace {

std::vector<uint8_t> wire_of(const Ping& p, uint32_t seq, uint8_t flags = 0) {
  std::vector<uint8_t> out(kMaxWireBytes);
  const std::size_t n = encode_message(p, seq, flags, out.data(), out.size());
  out.resize(n);
  return out;
}

struct Collected {
  std::vector<uint32_t> seqs;
  std::vector<Reject> rejects;
};

Collected feed(StreamDecoder& dec, const std::vector<uint8_t>& bytes) {
  Collected c;
  for (uint8_t b : bytes) {
    switch (dec.push(b)) {
      case StreamDecoder::Status::frame: c.seqs.push_back(dec.header().seq); break;
      case StreamDecoder::Status::rejected: c.rejects.push_back(dec.last_reject()); break;
      case StreamDecoder::Status::pending: break;
    }
  }
  return c;
}

TEST(ProtocolCrc32, MatchesTheIeeeCheckValue) {
  const char* s = "123456789";
  EXPECT_EQ(crc32(reinterpret_cast<const uint8_t*>(s), 9), 0xCBF43926u);
}

TEST(ProtocolCrc32, IsIncrementalLikeZlib) {
  const uint8_t a[] = {1, 2, 3, 4, 5, 6, 7};
  EXPECT_EQ(crc32(a + 3, 4, crc32(a, 3)), crc32(a, 7));
}

TEST(ProtocolCobs, RoundTripsEveryLengthAndNeverEmitsZero) {
  std::mt19937 rng(7);
  for (std::size_t len = 0; len <= kMaxFrameBytes; ++len) {
    std::vector<uint8_t> in(len);
    for (auto& b : in) b = static_cast<uint8_t>(rng() % 3 == 0 ? 0 : rng());
    std::vector<uint8_t> enc(cobs_max_encoded(len));
    const std::size_t n = cobs_encode(in.data(), len, enc.data(), enc.size());
    ASSERT_GT(n, 0u);
    for (std::size_t i = 0; i < n; ++i) ASSERT_NE(enc[i], 0) << "len " << len;
    std::vector<uint8_t> dec(kMaxFrameBytes + 1);
    std::size_t m = 0;
    ASSERT_TRUE(cobs_decode(enc.data(), n, dec.data(), dec.size(), m));
    dec.resize(m);
    EXPECT_EQ(dec, in);
  }
}

TEST(ProtocolCobs, RejectsACodeBytePointingPastTheEnd) {
  const uint8_t bad[] = {0x05, 0x11, 0x22};
  uint8_t out[8];
  std::size_t n = 0;
  EXPECT_FALSE(cobs_decode(bad, sizeof bad, out, sizeof out, n));
}

TEST(ProtocolFrame, EncoderRefusesAnOversizedBodyRatherThanTruncate) {
  std::vector<uint8_t> body(kMaxBodyBytes + 1, 0x55);
  std::vector<uint8_t> out(1024);
  EXPECT_EQ(encode_frame(FrameHeader{}, body.data(), body.size(), out.data(), out.size()), 0u);
  body.resize(kMaxBodyBytes);
  EXPECT_GT(encode_frame(FrameHeader{}, body.data(), body.size(), out.data(), out.size()), 0u);
  EXPECT_EQ(encode_frame(FrameHeader{}, body.data(), body.size(), out.data(), 10), 0u);
}

TEST(ProtocolFrame, MaximumLengthLogFitsTheWireLimit) {
  Log log;
  log.t_us = UINT64_MAX;
  log.level = 5;
  std::memset(log.text, 0xFF, sizeof log.text);
  log.text_len = sizeof log.text;
  std::vector<uint8_t> out(kMaxWireBytes);
  const std::size_t n = encode_message(log, 1, 0, out.data(), out.size());
  ASSERT_GT(n, 0u);
  EXPECT_LE(n, kMaxWireBytes);
}

TEST(ProtocolDecoder, DecodesEveryMessageSplitAtEveryByte) {
  Exposure e;
  e.image_index = 42;
  e.trigger_t_us = 1234567890123ull;
  e.feedback_start_t_us = 1234567890999ull;
  e.duration_us = 1000;
  std::vector<uint8_t> out(kMaxWireBytes);
  out.resize(encode_message(e, 9, 0, out.data(), out.size()));
  StreamDecoder dec;
  int frames = 0;
  for (uint8_t b : out) {
    if (dec.push(b) == StreamDecoder::Status::frame) {
      ++frames;
      Exposure got;
      ASSERT_TRUE(dec.decode(got));
      EXPECT_EQ(got.image_index, 42u);
      EXPECT_EQ(got.trigger_t_us, e.trigger_t_us);
      EXPECT_EQ(got.duration_us, 1000u);
      Ping wrong;
      EXPECT_FALSE(dec.decode(wrong));
    }
  }
  EXPECT_EQ(frames, 1);
}

TEST(ProtocolDecoder, CountsMissedSequenceNumbersAndIgnoresRetransmits) {
  StreamDecoder dec;
  std::vector<uint8_t> s;
  for (uint32_t seq : {10u, 11u, 15u}) {
    auto w = wire_of(Ping{}, seq);
    s.insert(s.end(), w.begin(), w.end());
  }
  auto re = wire_of(Ping{}, 12, FrameFlags::retransmit);
  s.insert(s.end(), re.begin(), re.end());
  auto next = wire_of(Ping{}, 16);
  s.insert(s.end(), next.begin(), next.end());
  auto reboot = wire_of(Ping{}, 0);
  s.insert(s.end(), reboot.begin(), reboot.end());
  const auto c = feed(dec, s);
  EXPECT_EQ(c.seqs.size(), 6u);
  EXPECT_EQ(dec.stats().seq_gaps, 1u);
  EXPECT_EQ(dec.stats().seq_missed, 3u);
  EXPECT_EQ(dec.stats().seq_resets, 1u);
}

TEST(ProtocolDecoder, MissedCountSaturatesInsteadOfWrapping) {
  StreamDecoder dec;
  std::vector<uint8_t> s;
  // Three gaps of 2^31 - 2 frames each: 3 * (2^31 - 2) > 2^32 - 1, which a wrapping u32 would show as small.
  for (uint32_t seq : {0u, 0x7FFFFFFFu, 0xFFFFFFFEu, 0x7FFFFFFDu}) {
    auto w = wire_of(Ping{}, seq);
    s.insert(s.end(), w.begin(), w.end());
  }
  const auto c = feed(dec, s);
  EXPECT_EQ(c.seqs.size(), 4u);
  EXPECT_EQ(dec.stats().seq_gaps, 3u);
  EXPECT_EQ(dec.stats().seq_missed, UINT32_MAX);
}

TEST(ProtocolDecoder, SequenceWrapsWithoutCountingAGap) {
  StreamDecoder dec;
  std::vector<uint8_t> s;
  for (uint32_t seq : {0xFFFFFFFEu, 0xFFFFFFFFu, 0u, 1u}) {
    auto w = wire_of(Ping{}, seq);
    s.insert(s.end(), w.begin(), w.end());
  }
  feed(dec, s);
  EXPECT_EQ(dec.stats().frames_ok, 4u);
  EXPECT_EQ(dec.stats().seq_gaps, 0u);
  EXPECT_EQ(dec.stats().seq_resets, 0u);
}

TEST(ProtocolDecoder, EveryRejectionIsCountedOnceAndTheNextFrameDecodes) {
  StreamDecoder dec;
  auto good = wire_of(Ping{}, 1);
  // Flip one body bit below the COBS layer so only the CRC can catch it.
  uint8_t raw[kMaxFrameBytes];
  std::size_t raw_len = 0;
  ASSERT_TRUE(cobs_decode(good.data(), good.size() - 1, raw, sizeof raw, raw_len));
  raw[kHeaderBytes] ^= 0x01;
  std::vector<uint8_t> bad_crc(kMaxWireBytes);
  bad_crc.resize(cobs_encode(raw, raw_len, bad_crc.data(), bad_crc.size()));
  bad_crc.push_back(0);
  std::vector<uint8_t> oversized(400, 0x42);
  oversized.push_back(0);
  std::vector<uint8_t> s = bad_crc;
  s.insert(s.end(), oversized.begin(), oversized.end());
  s.insert(s.end(), {0x05, 0x01, 0x00});  // COBS code past the end
  s.insert(s.end(), {0x03, 0x01, 0x02, 0x00});  // truncated (2 bytes)
  s.insert(s.end(), good.begin(), good.end());
  const auto c = feed(dec, s);
  ASSERT_EQ(c.seqs.size(), 1u);
  EXPECT_EQ(dec.stats().crc_error, 1u);
  EXPECT_EQ(dec.stats().oversized, 1u);
  EXPECT_EQ(dec.stats().cobs_error, 1u);
  EXPECT_EQ(dec.stats().truncated, 1u);
  EXPECT_EQ(dec.stats().rejected(), 4u);
}

TEST(ProtocolDecoder, RandomBytesNeverBreakItAndAValidFrameAlwaysFollows) {
  std::mt19937 rng(1234);
  StreamDecoder dec;
  const auto good = wire_of(Ping{}, 77);
  for (int round = 0; round < 2000; ++round) {
    std::vector<uint8_t> junk(rng() % 600);
    for (auto& b : junk) b = static_cast<uint8_t>(rng());
    junk.push_back(0);  // the junk ends at a delimiter, as after any real glitch
    const uint32_t before = dec.stats().frames_ok + dec.stats().rejected();
    feed(dec, junk);
    const auto c = feed(dec, good);
    ASSERT_EQ(c.seqs.size(), 1u) << "round " << round;
    EXPECT_EQ(c.seqs[0], 77u);
    EXPECT_GE(dec.stats().frames_ok + dec.stats().rejected(), before + 1);
  }
}

}  // namespace
}  // namespace icgt::proto
