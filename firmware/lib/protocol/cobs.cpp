#include "cobs.hpp"

namespace icgt::proto {

std::size_t cobs_encode(const uint8_t* in, std::size_t len, uint8_t* out, std::size_t cap) {
  if (cap < cobs_max_encoded(len)) return 0;
  std::size_t code_pos = 0;
  std::size_t o = 1;
  uint8_t code = 1;
  for (std::size_t i = 0; i < len; ++i) {
    if (in[i] == 0) {
      out[code_pos] = code;
      code_pos = o++;
      code = 1;
      continue;
    }
    out[o++] = in[i];
    if (++code == 0xFF) {
      out[code_pos] = code;
      code_pos = o++;
      code = 1;
    }
  }
  out[code_pos] = code;
  return o;
}

bool cobs_decode(const uint8_t* in, std::size_t len, uint8_t* out, std::size_t cap, std::size_t& out_len) {
  std::size_t i = 0;
  std::size_t o = 0;
  while (i < len) {
    const uint8_t code = in[i++];
    if (code == 0) return false;
    const std::size_t run = static_cast<std::size_t>(code) - 1;
    if (run > len - i || o + run > cap) return false;
    for (std::size_t k = 0; k < run; ++k) {
      if (in[i] == 0) return false;
      out[o++] = in[i++];
    }
    if (code != 0xFF && i < len) {
      if (o >= cap) return false;
      out[o++] = 0;
    }
  }
  out_len = o;
  return true;
}

}  // namespace icgt::proto
