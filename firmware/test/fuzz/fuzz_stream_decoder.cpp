// libFuzzer target for the stream decoder (SPEC.md §7): any bytes, fed in pieces whose
// sizes come from the input itself; checks the invariants that can be checked from outside.
//   make fuzz   (clang++ -fsanitize=fuzzer,address,undefined)
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "frame.hpp"

using icgt::proto::StreamDecoder;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  StreamDecoder dec;
  uint32_t completed = 0;
  for (std::size_t i = 0; i < size; ++i) {
    switch (dec.push(data[i])) {
      case StreamDecoder::Status::frame: {
        ++completed;
        // A frame that passed the CRC decodes into its own type, whatever it is.
        bool decoded = false;
        const bool known = icgt::proto::with_message_type(dec.header().type, [&](auto msg) {
          decoded = dec.decode(msg);
        });
        if (!known || !decoded) std::abort();
        break;
      }
      case StreamDecoder::Status::rejected: ++completed; break;
      case StreamDecoder::Status::pending: break;
    }
    if (dec.pending_bytes() > icgt::proto::kMaxWireBytes) std::abort();  // invariant 2
  }
  // Invariant 4: one counter per completed candidate.
  if (dec.stats().frames_ok + dec.stats().rejected() != completed) std::abort();
  // Invariant 5: after a delimiter, a valid frame decodes.
  uint8_t frame[icgt::proto::kMaxWireBytes];
  icgt::proto::Ping ping;
  ping.nonce = 0xA5A5A5A5u;
  const std::size_t n = icgt::proto::encode_message(ping, 1, 0, frame, sizeof frame);
  (void)dec.push(0);
  bool got = false;
  for (std::size_t i = 0; i < n; ++i) got = dec.push(frame[i]) == StreamDecoder::Status::frame || got;
  icgt::proto::Ping back;
  if (!got || !dec.decode(back) || back.nonce != ping.nonce) std::abort();
  return 0;
}
