#include "frame.hpp"

#include "crc32.hpp"
#include "wire.hpp"

#include <cstdint>

namespace icgt::proto {

std::size_t encode_frame(const FrameHeader& header, const uint8_t* body, std::size_t body_len, uint8_t* out,
                         std::size_t cap) {
  if (body_len > kMaxBodyBytes) return 0;
  uint8_t raw[kMaxFrameBytes];
  raw[0] = header.version;
  raw[1] = header.type;
  raw[2] = header.flags;
  raw[3] = 0;
  wire::put(raw + 4, header.seq);
  for (std::size_t i = 0; i < body_len; ++i) raw[kHeaderBytes + i] = body[i];
  const std::size_t n = kHeaderBytes + body_len;
  wire::put(raw + n, crc32(raw, n));
  if (cap == 0) return 0;
  const std::size_t enc = cobs_encode(raw, n + kCrcBytes, out, cap - 1);
  if (enc == 0) return 0;
  out[enc] = 0;
  return enc + 1;
}

StreamDecoder::Status StreamDecoder::push(uint8_t byte) {
  if (byte != 0) {
    if (pending_ < kMaxEncodedBytes) encoded_[pending_] = byte;
    // Past the limit the bytes are only counted, never stored (SPEC.md §6 rule b).
    if (pending_ <= kMaxEncodedBytes) ++pending_;
    return Status::pending;
  }
  if (pending_ == 0) return Status::pending;  // rule a: empty frames are idle fill
  const Status s = finish_candidate();
  pending_ = 0;
  return s;
}

StreamDecoder::Status StreamDecoder::reject(Reject why) {
  last_reject_ = why;
  switch (why) {
    case Reject::oversized: ++stats_.oversized; break;
    case Reject::cobs_error: ++stats_.cobs_error; break;
    case Reject::truncated: ++stats_.truncated; break;
    case Reject::crc_error: ++stats_.crc_error; break;
    case Reject::wrong_version: ++stats_.wrong_version; break;
    case Reject::unknown_type: ++stats_.unknown_type; break;
    case Reject::bad_length: ++stats_.bad_length; break;
    case Reject::none: break;
  }
  return Status::rejected;
}

StreamDecoder::Status StreamDecoder::finish_candidate() {
  if (pending_ > kMaxEncodedBytes) return reject(Reject::oversized);
  std::size_t n = 0;
  if (!cobs_decode(encoded_, pending_, decoded_, sizeof decoded_, n)) return reject(Reject::cobs_error);
  if (n < kHeaderBytes + kCrcBytes) return reject(Reject::truncated);
  const std::size_t covered = n - kCrcBytes;
  if (crc32(decoded_, covered) != wire::get<uint32_t>(decoded_ + covered)) return reject(Reject::crc_error);
  // The CRC passed, so the header can be trusted even if the frame is refused below: a
  // device can then answer an unknown or malformed command with a NACK naming its seq.
  header_.version = decoded_[0];
  header_.type = decoded_[1];
  header_.flags = decoded_[2];
  header_.seq = wire::get<uint32_t>(decoded_ + 4);
  body_len_ = covered - kHeaderBytes;
  if (decoded_[0] != kProtocolVersion) {
    stats_.last_foreign_version = decoded_[0];
    return reject(Reject::wrong_version);
  }
  std::size_t min_len = 0;
  std::size_t max_len = 0;
  if (!body_size_range(decoded_[1], min_len, max_len)) return reject(Reject::unknown_type);
  if (body_len_ < min_len || body_len_ > max_len) return reject(Reject::bad_length);
  last_reject_ = Reject::none;
  ++stats_.frames_ok;
  track_sequence();
  return Status::frame;
}

void StreamDecoder::track_sequence() {
  if ((header_.flags & FrameFlags::retransmit) != 0) return;  // resends keep their old seq
  if (have_expected_seq_ && header_.seq != expected_seq_) {
    const uint32_t d = header_.seq - expected_seq_;  // modulo 2^32 by unsigned arithmetic
    if (d < 0x80000000u) {
      ++stats_.seq_gaps;
      // Saturate, never wrap: a counter gone round to 0 would report a huge loss as none (SPEC.md §3).
      const uint32_t room = UINT32_MAX - stats_.seq_missed;
      stats_.seq_missed = d > room ? UINT32_MAX : stats_.seq_missed + d;
    } else {
      ++stats_.seq_resets;
    }
  }
  have_expected_seq_ = true;
  expected_seq_ = header_.seq + 1;
}

}  // namespace icgt::proto
