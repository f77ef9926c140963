#include "crc32.hpp"

#include <array>

namespace icgt::proto {
namespace {

// A 256-entry table costs 1 KiB of flash and makes the CRC about 8x faster than the bitwise
// loop; at 0.5 MB/s of link traffic the bitwise form would eat a visible share of a Teensy 3.6.
constexpr std::array<uint32_t, 256> make_table() {
  std::array<uint32_t, 256> table{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? (0xEDB88320u ^ (c >> 1)) : (c >> 1);
    table[i] = c;
  }
  return table;
}

constexpr std::array<uint32_t, 256> kTable = make_table();

}  // namespace

uint32_t crc32(const uint8_t* data, std::size_t len, uint32_t crc) {
  uint32_t c = ~crc;
  for (std::size_t i = 0; i < len; ++i) c = kTable[(c ^ data[i]) & 0xFFu] ^ (c >> 8);
  return ~c;
}

}  // namespace icgt::proto
