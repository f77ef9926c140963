// Little-endian field access for the ICGT wire format (SPEC.md §2). Works on any host
// byte order and never performs an unaligned load: fields are copied byte by byte.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace icgt::proto::wire {

// A string field as it sits in a message (not NUL-terminated).
struct StrView {
  const char* data;
  std::size_t len;
};

[[nodiscard]] inline std::size_t strnlen_bounded(const char* s, std::size_t max_len) {
  std::size_t n = 0;
  while (n < max_len && s[n] != '\0') ++n;
  return n;
}

template <class T>
void put(uint8_t* out, T value) {
  static_assert(std::is_arithmetic_v<T>, "wire fields are integers or IEEE floats");
  using U = std::conditional_t<sizeof(T) == 1, uint8_t,
            std::conditional_t<sizeof(T) == 2, uint16_t,
            std::conditional_t<sizeof(T) == 4, uint32_t, uint64_t>>>;
  U bits;
  std::memcpy(&bits, &value, sizeof(T));
  for (std::size_t i = 0; i < sizeof(T); ++i) {
    out[i] = static_cast<uint8_t>(bits >> (8 * i));
  }
}

template <class T>
[[nodiscard]] T get(const uint8_t* in) {
  static_assert(std::is_arithmetic_v<T>, "wire fields are integers or IEEE floats");
  using U = std::conditional_t<sizeof(T) == 1, uint8_t,
            std::conditional_t<sizeof(T) == 2, uint16_t,
            std::conditional_t<sizeof(T) == 4, uint32_t, uint64_t>>>;
  U bits = 0;
  for (std::size_t i = 0; i < sizeof(T); ++i) {
    bits = static_cast<U>(bits | (static_cast<U>(in[i]) << (8 * i)));
  }
  T value;
  std::memcpy(&value, &bits, sizeof(T));
  return value;
}

}  // namespace icgt::proto::wire
