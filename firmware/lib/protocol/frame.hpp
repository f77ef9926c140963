// Framing of the ICGT wire protocol (SPEC.md §1-§7): header + body + CRC-32, COBS, 0x00.
// FrameEncoder builds complete wire frames into caller buffers; StreamDecoder is fed one
// byte or a buffer at a time and reports each completed frame or why it was rejected.
// Neither touches I/O or the heap.
#pragma once

#include <cstddef>
#include <cstdint>

#include "cobs.hpp"
#include "messages.hpp"

namespace icgt::proto {

// Encoded frame between delimiters, and with its delimiter.
inline constexpr std::size_t kMaxEncodedBytes = cobs_max_encoded(kMaxFrameBytes);
inline constexpr std::size_t kMaxWireBytes = kMaxEncodedBytes + 1;
static_assert(kMaxEncodedBytes == 258, "SPEC.md §5 promises 258 encoded bytes");

struct FrameHeader {
  uint8_t version = kProtocolVersion;
  uint8_t type = 0;
  uint8_t flags = 0;
  uint32_t seq = 0;
};

// Builds the wire form (COBS + trailing 0x00) of one frame. Returns the bytes written, or 0
// if the body is too long or cap too small (invariant 8: refuse, never truncate).
[[nodiscard]] std::size_t encode_frame(const FrameHeader& header, const uint8_t* body, std::size_t body_len,
                                       uint8_t* out, std::size_t cap);

template <class Msg>
[[nodiscard]] std::size_t encode_message(const Msg& msg, uint32_t seq, uint8_t flags, uint8_t* out,
                                         std::size_t cap) {
  uint8_t body[kMaxBodyBytes];
  const std::size_t n = msg.encode(body, sizeof body);
  if (n == 0 && Msg::kMinBodyBytes != 0) return 0;
  FrameHeader h;
  h.type = static_cast<uint8_t>(Msg::kId);
  h.flags = flags;
  h.seq = seq;
  return encode_frame(h, body, n, out, cap);
}

// Why a candidate frame was rejected (SPEC.md §6, rules b-h).
enum class Reject : uint8_t {
  none = 0,
  oversized,
  cobs_error,
  truncated,
  crc_error,
  wrong_version,
  unknown_type,
  bad_length,
};

struct DecoderStats {
  uint32_t frames_ok = 0;
  uint32_t oversized = 0;
  uint32_t cobs_error = 0;
  uint32_t truncated = 0;
  uint32_t crc_error = 0;
  uint32_t wrong_version = 0;
  uint32_t unknown_type = 0;
  uint32_t bad_length = 0;
  uint32_t seq_gaps = 0;
  uint32_t seq_missed = 0;
  uint32_t seq_resets = 0;
  uint8_t last_foreign_version = 0;  // version byte of the last wrong_version frame

  [[nodiscard]] uint32_t rejected() const {
    return oversized + cobs_error + truncated + crc_error + wrong_version + unknown_type + bad_length;
  }
};

class StreamDecoder {
 public:
  enum class Status : uint8_t {
    pending,   // byte taken, no frame completed
    frame,     // a valid frame completed: header() and body() describe it until the next push
    rejected,  // a candidate frame completed and was rejected: last_reject() says why;
               // for wrong_version, unknown_type and bad_length (CRC passed) header() is valid
  };

  [[nodiscard]] Status push(uint8_t byte);

  [[nodiscard]] const FrameHeader& header() const { return header_; }
  [[nodiscard]] const uint8_t* body() const { return decoded_ + kHeaderBytes; }
  [[nodiscard]] std::size_t body_len() const { return body_len_; }
  [[nodiscard]] Reject last_reject() const { return last_reject_; }
  [[nodiscard]] const DecoderStats& stats() const { return stats_; }
  // Bytes of a frame in progress (without a delimiter yet).
  [[nodiscard]] std::size_t pending_bytes() const { return pending_; }

  // Decodes the current frame's body into msg; false if the type does not match.
  template <class Msg>
  [[nodiscard]] bool decode(Msg& msg) const {
    return header_.type == static_cast<uint8_t>(Msg::kId) && msg.decode(body(), body_len_);
  }

 private:
  [[nodiscard]] Status finish_candidate();
  [[nodiscard]] Status reject(Reject why);
  void track_sequence();

  uint8_t encoded_[kMaxEncodedBytes]{};
  uint8_t decoded_[kMaxFrameBytes]{};
  std::size_t pending_ = 0;  // bytes seen since the last delimiter (may exceed the buffer)
  FrameHeader header_{};
  std::size_t body_len_ = 0;
  Reject last_reject_ = Reject::none;
  DecoderStats stats_{};
  bool have_expected_seq_ = false;
  uint32_t expected_seq_ = 0;
};

}  // namespace icgt::proto
