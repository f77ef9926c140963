// CRC-32 (IEEE 802.3, reflected 0xEDB88320), identical to Python's zlib.crc32 (SPEC.md §1).
#pragma once

#include <cstddef>
#include <cstdint>

namespace icgt::proto {

// Incremental like zlib: crc32(b, n_b, crc32(a, n_a)) == crc32(a+b). Start with 0.
[[nodiscard]] uint32_t crc32(const uint8_t* data, std::size_t len, uint32_t crc = 0);

}  // namespace icgt::proto
