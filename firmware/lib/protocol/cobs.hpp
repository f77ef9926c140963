// Consistent Overhead Byte Stuffing (SPEC.md §1, §6): removes every 0x00 from a frame so a
// single 0x00 can delimit it. Written here rather than taken from a library because the
// firmware needs a no-heap, bounds-checked version that also runs on a Cortex-M.
#pragma once

#include <cstddef>
#include <cstdint>

namespace icgt::proto {

// Worst-case encoded size of len bytes (without the delimiter).
[[nodiscard]] constexpr std::size_t cobs_max_encoded(std::size_t len) { return len + len / 254 + 1; }

// Encodes len bytes into out (no delimiter). Returns the encoded size, 0 if cap is too small.
[[nodiscard]] std::size_t cobs_encode(const uint8_t* in, std::size_t len, uint8_t* out, std::size_t cap);

// Decodes an encoded block (no delimiter). Returns false if the block is not valid COBS
// (a zero byte, or a code byte pointing past the end) or the output would exceed cap.
[[nodiscard]] bool cobs_decode(const uint8_t* in, std::size_t len, uint8_t* out, std::size_t cap,
                               std::size_t& out_len);

}  // namespace icgt::proto
