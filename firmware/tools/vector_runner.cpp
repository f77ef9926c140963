// Decodes a protocol test vector (a raw byte stream) with the C++ codec and prints the
// canonical JSON of SPEC.md §9, which tests/conformance compares with the expected file
// and with the Python runner's output.
//
//   icgt-vector-runner FILE.bin
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <type_traits>
#include <vector>

#include "frame.hpp"

namespace {

using icgt::proto::StreamDecoder;
namespace wire = icgt::proto::wire;

void append_json_string(std::string& out, const char* s, std::size_t n) {
  out += '"';
  for (std::size_t i = 0; i < n; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += static_cast<char>(c);
    } else if (c < 0x20 || c == 0x7F) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      out += buf;
    } else {
      out += static_cast<char>(c);
    }
  }
  out += '"';
}

void append_double(std::string& out, double v) {
  if (std::isnan(v)) {
    out += "\"NaN\"";
  } else if (std::isinf(v)) {
    out += v > 0 ? "\"Infinity\"" : "\"-Infinity\"";
  } else {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    out += buf;
  }
}

// Fields arrive in wire order; canonical JSON wants keys sorted, so collect then sort.
struct FieldCollector {
  std::vector<std::pair<std::string, std::string>> items;

  template <class T>
  void operator()(const char* name, const T& value) {
    std::string v;
    if constexpr (std::is_same_v<T, wire::StrView>) {
      append_json_string(v, value.data, value.len);
    } else if constexpr (std::is_floating_point_v<T>) {
      append_double(v, static_cast<double>(value));
    } else if constexpr (std::is_signed_v<T>) {
      v = std::to_string(static_cast<long long>(value));
    } else {
      v = std::to_string(static_cast<unsigned long long>(value));
    }
    items.emplace_back(name, v);
  }
};

std::string object(std::vector<std::pair<std::string, std::string>> items) {
  std::sort(items.begin(), items.end());
  std::string out = "{";
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (i) out += ',';
    append_json_string(out, items[i].first.data(), items[i].first.size());
    out += ':';
    out += items[i].second;
  }
  return out + "}";
}

std::string decode_current(const StreamDecoder& dec) {
  std::string fields;
  bool ok = false;
  const bool known = icgt::proto::with_message_type(dec.header().type, [&](auto msg) {
    if (dec.decode(msg)) {
      FieldCollector c;
      msg.visit(c);
      fields = object(c.items);
      ok = true;
    }
  });
  if (!known || !ok) return {};
  std::string type;
  const char* name = icgt::proto::msg_name(dec.header().type);
  append_json_string(type, name, std::char_traits<char>::length(name));
  return object({{"fields", fields},
                 {"flags", std::to_string(dec.header().flags)},
                 {"seq", std::to_string(dec.header().seq)},
                 {"type", type}});
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s VECTOR.bin\n", argv[0]);
    return 2;
  }
  std::FILE* f = std::fopen(argv[1], "rb");
  if (f == nullptr) {
    std::perror(argv[1]);
    return 2;
  }
  StreamDecoder dec;
  std::string messages = "[";
  bool first = true;
  int c;
  while ((c = std::fgetc(f)) != EOF) {
    if (dec.push(static_cast<uint8_t>(c)) != StreamDecoder::Status::frame) continue;
    const std::string m = decode_current(dec);
    if (m.empty()) {
      std::fprintf(stderr, "%s: a frame the decoder accepted did not decode\n", argv[1]);
      return 1;
    }
    if (!first) messages += ',';
    messages += m;
    first = false;
  }
  std::fclose(f);
  messages += "]";
  const auto& s = dec.stats();
  auto u = [](uint64_t v) { return std::to_string(v); };
  const std::string stats = object({{"frames_ok", u(s.frames_ok)},
                                    {"oversized", u(s.oversized)},
                                    {"cobs_error", u(s.cobs_error)},
                                    {"truncated", u(s.truncated)},
                                    {"crc_error", u(s.crc_error)},
                                    {"wrong_version", u(s.wrong_version)},
                                    {"unknown_type", u(s.unknown_type)},
                                    {"bad_length", u(s.bad_length)},
                                    {"seq_gaps", u(s.seq_gaps)},
                                    {"seq_missed", u(s.seq_missed)},
                                    {"seq_resets", u(s.seq_resets)},
                                    {"pending_bytes", u(dec.pending_bytes())}});
  std::printf("%s\n", object({{"messages", messages}, {"stats", stats}}).c_str());
  return 0;
}
