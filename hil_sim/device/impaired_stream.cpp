#include "device/impaired_stream.hpp"

#include <time.h>

namespace icgt::sim {

uint64_t monotonic_now_ns() {
  timespec ts{};
  ::clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1'000'000'000u + static_cast<uint64_t>(ts.tv_nsec);
}

ImpairedStream::ImpairedStream(HostPort& port, const ClockMap& map, uint64_t seed)
    : port_(port), map_(map), frame_anchor_ns_(map.t0_monotonic_ns), rng_(seed) {}

uint64_t ImpairedStream::next_frame_ns(uint64_t ns, uint64_t frame_ns) const {
  // The first frame boundary after ns, on a grid through the anchor (which may lie ahead of ns).
  const auto f = static_cast<int64_t>(frame_ns);
  const int64_t since = static_cast<int64_t>(ns - frame_anchor_ns_);  // two's complement: negative if ahead
  const int64_t floor_div = since >= 0 ? since / f : -((-since + f - 1) / f);
  return frame_anchor_ns_ + static_cast<uint64_t>((floor_div + 1) * f);
}

uint64_t ImpairedStream::jitter_ns() {
  if (impairment_.jitter_us == 0) return 0;
  std::uniform_int_distribution<uint64_t> d(0, static_cast<uint64_t>(impairment_.jitter_us) * 1000u);
  return d(rng_);
}

bool ImpairedStream::corrupt(uint8_t& byte) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  if (impairment_.drop_probability > 0.0 && u(rng_) < impairment_.drop_probability) {
    ++counters_.dropped;
    return false;
  }
  if (impairment_.flip_probability > 0.0 && u(rng_) < impairment_.flip_probability) {
    byte = static_cast<uint8_t>(byte ^ (1u << (rng_() % 8)));
    ++counters_.flipped;
  }
  return true;
}

std::size_t ImpairedStream::writable() const {
  return connected_ && to_host_.size() < kTxCapacity ? kTxCapacity - to_host_.size() : 0;
}

std::size_t ImpairedStream::write(const uint8_t* data, std::size_t len) {
  const std::size_t n = len < writable() ? len : writable();
  if (n == 0) return 0;
  // The bytes leave with the host's next poll of the IN endpoint: the next frame boundary
  // (frames counted from the scenario origin) plus host-side jitter.
  const uint64_t written_ns = map_.monotonic_ns_at_device(clock_->now_us());
  const uint64_t frame_ns = static_cast<uint64_t>(impairment_.frame_us) * 1000u;
  uint64_t release = written_ns;
  if (frame_ns > 0) release = next_frame_ns(written_ns, frame_ns);
  release += jitter_ns();
  if (!to_host_.empty() && release < to_host_.back().release) release = to_host_.back().release;  // FIFO
  for (std::size_t i = 0; i < n; ++i) {
    uint8_t b = data[i];
    if (corrupt(b)) to_host_.push_back({release, b});
  }
  return n;
}

std::size_t ImpairedStream::read(uint8_t* out, std::size_t cap) {
  const uint64_t now = clock_->now_us();
  std::size_t n = 0;
  while (n < cap && !to_device_.empty() && to_device_.front().release <= now) {
    out[n++] = to_device_.front().byte;
    to_device_.pop_front();
  }
  counters_.bytes_to_device += n;
  return n;
}

void ImpairedStream::pump(uint64_t now_monotonic_ns) {
  const bool was = connected_;
  connected_ = !unplugged_ && port_.connected();
  if (!connected_) {
    if (was) {
      to_host_.clear();
      to_device_.clear();
    }
    return;
  }
  uint8_t buf[512];
  // Host OUT transfers reach the device in the next frame too.
  const uint64_t frame_ns = static_cast<uint64_t>(impairment_.frame_us) * 1000u;
  for (;;) {
    const std::size_t n = port_.read_some(buf, sizeof buf);
    if (n == 0) break;
    // Read the clock after the bytes are in hand: a time taken earlier in the loop could come
    // before they were even sent, and the device would then see them before the host sent them.
    uint64_t arrive_ns = std::max(now_monotonic_ns, monotonic_now_ns());
    if (frame_ns > 0) arrive_ns = next_frame_ns(arrive_ns, frame_ns);
    arrive_ns += jitter_ns();
    uint64_t release_us = map_.device_us_at_tau(map_.tau_s_at_monotonic(arrive_ns));
    if (!to_device_.empty() && release_us < to_device_.back().release) release_us = to_device_.back().release;
    for (std::size_t i = 0; i < n; ++i) {
      uint8_t b = buf[i];
      if (corrupt(b)) to_device_.push_back({release_us, b});
    }
  }
  while (!to_host_.empty() && to_host_.front().release <= now_monotonic_ns) {
    std::size_t run = 0;
    while (run < sizeof buf && run < to_host_.size() && to_host_[run].release <= now_monotonic_ns) {
      buf[run] = to_host_[run].byte;
      ++run;
    }
    const std::size_t sent = port_.write_some(buf, run);
    for (std::size_t i = 0; i < sent; ++i) to_host_.pop_front();
    counters_.bytes_to_host += sent;
    if (sent < run) break;  // the host is not reading: keep the rest (the device sees writable() shrink)
  }
}

void ImpairedStream::unplug() {
  unplugged_ = true;
  port_.unplug();
}

void ImpairedStream::replug() {
  unplugged_ = false;
  port_.replug();
}

}  // namespace icgt::sim
