// icgt-sim-device: the ICGT firmware on the simulated board, paced by the real clock and
// reachable like a real board (a serial device or a TCP port). See hil_sim/README.md.
#include <poll.h>
#include <sys/prctl.h>
#include <time.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>

#include "board/sim_board.hpp"
#include "device/control_socket.hpp"
#include "device/host_port.hpp"
#include "device/impaired_stream.hpp"
#include "device/truth_table.hpp"

namespace {

volatile std::sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }

struct Options {
  std::string link = "pty";
  std::string truth;
  std::string events_out;
  std::string control;
  uint64_t t0_monotonic_ns = 0;
  double device_offset_us = 0.0;
  double device_drift_ppm = 0.0;
  int64_t rtc_utc_s = 1'795'000'000;
  int64_t utc0_us = 0;
  bool pps = false;
  bool feedback = true;
  bool imu = true;
  bool lidar = true;
  std::string lidar_model = "v3";
  double range_noise_cm = 2.0;
  uint64_t seed = 1;
  icgt::sim::CameraModelConfig camera{};
  std::string camera_miss_triggers;  // comma-separated 1-based trigger indices
  icgt::sim::LinkImpairment impairment{};
};

[[noreturn]] void usage(const char* why) {
  std::fprintf(stderr,
               "icgt-sim-device: %s\n"
               "usage: icgt-sim-device --truth FILE [--t0-monotonic-ns N] [--link pty[:PATH]|tcp:PORT]\n"
               "  [--device-offset-us X] [--device-drift-ppm Y] [--rtc-utc-s S] [--utc0-us U] [--pps]\n"
               "  [--camera-latency-us N] [--camera-jitter-us N] [--camera-exposure-us N] [--camera-miss-every N]\n"
               "  [--camera-miss-triggers I,J,...] [--camera-min-frame-us N] [--camera-buffer-shots N]\n"
               "  [--camera-write-us N]\n"
               "  [--no-feedback] [--no-imu] [--no-lidar] [--lidar-model v3|v3hp] [--range-noise-cm S]\n"
               "  [--usb-frame-us N] [--usb-jitter-us N] [--seed N] [--events-out FILE] [--control PATH]\n"
               "see hil_sim/README.md\n",
               why);
  std::exit(2);
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage(("missing value for " + a).c_str());
      return argv[++i];
    };
    auto number = [&]() -> double {
      const std::string v = value();
      char* end = nullptr;
      const double d = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0') usage(("not a number for " + a + ": " + v).c_str());
      return d;
    };
    if (a == "--link") o.link = value();
    else if (a == "--truth") o.truth = value();
    else if (a == "--events-out") o.events_out = value();
    else if (a == "--control") o.control = value();
    else if (a == "--t0-monotonic-ns") o.t0_monotonic_ns = std::strtoull(value().c_str(), nullptr, 10);
    else if (a == "--device-offset-us") o.device_offset_us = number();
    else if (a == "--device-drift-ppm") o.device_drift_ppm = number();
    else if (a == "--rtc-utc-s") o.rtc_utc_s = static_cast<int64_t>(number());
    else if (a == "--utc0-us") o.utc0_us = std::strtoll(value().c_str(), nullptr, 10);
    else if (a == "--pps") o.pps = true;
    else if (a == "--no-feedback") o.feedback = false;
    else if (a == "--no-imu") o.imu = false;
    else if (a == "--no-lidar") o.lidar = false;
    else if (a == "--lidar-model") o.lidar_model = value();
    else if (a == "--range-noise-cm") o.range_noise_cm = number();
    else if (a == "--seed") o.seed = static_cast<uint64_t>(number());
    else if (a == "--camera-latency-us") o.camera.latency_us = static_cast<uint32_t>(number());
    else if (a == "--camera-jitter-us") o.camera.latency_jitter_us = static_cast<uint32_t>(number());
    else if (a == "--camera-exposure-us") o.camera.exposure_us = static_cast<uint32_t>(number());
    else if (a == "--camera-miss-every") o.camera.miss_every = static_cast<uint32_t>(number());
    else if (a == "--camera-miss-triggers") o.camera_miss_triggers = value();
    else if (a == "--camera-min-frame-us") o.camera.min_frame_period_us = static_cast<uint32_t>(number());
    else if (a == "--camera-buffer-shots") o.camera.buffer_shots = static_cast<uint32_t>(number());
    else if (a == "--camera-write-us") o.camera.write_us = static_cast<uint32_t>(number());
    else if (a == "--usb-frame-us") o.impairment.frame_us = static_cast<uint32_t>(number());
    else if (a == "--usb-jitter-us") o.impairment.jitter_us = static_cast<uint32_t>(number());
    else if (a == "--help" || a == "-h") usage("help");
    else usage(("unknown option " + a).c_str());
  }
  if (o.lidar_model != "v3" && o.lidar_model != "v3hp") usage("--lidar-model is v3 or v3hp");
  return o;
}

class EventLog {
 public:
  explicit EventLog(const std::string& path) {
    if (!path.empty()) f_ = std::fopen(path.c_str(), "w");
    if (!path.empty() && f_ == nullptr) {
      std::fprintf(stderr, "icgt-sim-device: cannot write %s: %s\n", path.c_str(), std::strerror(errno));
      std::exit(1);
    }
  }
  ~EventLog() {
    if (f_ != nullptr) std::fclose(f_);
  }
  void line(const std::string& json) {
    if (f_ == nullptr) return;
    std::fputs(json.c_str(), f_);
    std::fputc('\n', f_);
    std::fflush(f_);
  }

 private:
  std::FILE* f_ = nullptr;
};

std::string exposure_json(const icgt::sim::TrueExposure& e) {
  std::ostringstream s;
  s << R"({"event":"exposure","frame_number":)" << e.frame_number << R"(,"trigger_index":)" << e.trigger_index
    << R"(,"trigger_t_us":)" << e.trigger_t_us << R"(,"start_t_us":)" << e.start_t_us << R"(,"end_t_us":)"
    << e.end_t_us << R"(,"manual":)" << (e.manual ? "true" : "false") << "}";
  return s.str();
}

std::string ignored_json(const icgt::sim::IgnoredTrigger& t) {
  std::ostringstream s;
  s << R"({"event":"trigger_ignored","trigger_index":)" << t.trigger_index << R"(,"trigger_t_us":)" << t.trigger_t_us
    << R"(,"reason":")" << icgt::sim::ignored_reason_name(t.reason) << R"("})";
  return s.str();
}

// Sleeps until the host sends, a byte for the host is due, or kLoopPeriodNs pass (the board's
// sensors need stepping). A plain sleep of a loop period would add up to a period of latency
// to the link in each direction, a path delay and asymmetry a real USB link does not have.
void wait_for_host_or_due_bytes(const icgt::sim::ImpairedStream& link, const icgt::sim::HostPort& port) {
  constexpr uint64_t kLoopPeriodNs = 100'000;
  const uint64_t now = icgt::sim::monotonic_now_ns();
  const uint64_t due = link.next_release_ns();
  // Bytes already due are still queued only when the host's buffer is full (it is not reading):
  // waiting a period then instead of spinning on them.
  const uint64_t deadline = due > now ? std::min(now + kLoopPeriodNs, due) : now + kLoopPeriodNs;
  const uint64_t wait = deadline > now ? deadline - now : 0;
  const timespec ts{static_cast<time_t>(wait / 1'000'000'000u), static_cast<long>(wait % 1'000'000'000u)};
  const int fd = link.connected() ? port.readable_fd() : -1;  // a hung-up pty polls readable at once
  if (fd >= 0) {
    pollfd p{fd, POLLIN, 0};
    (void)::ppoll(&p, 1, &ts, nullptr);
  } else {
    (void)::nanosleep(&ts, nullptr);
  }
}

}  // namespace

int main(int argc, char** argv) {
  // Timers wake this process within 1 us instead of the default 50 us slack (the link's
  // latency is a modelled quantity; the simulator's own must stay far below it).
  (void)::prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  using namespace icgt::sim;
  Options opt = parse(argc, argv);
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  std::signal(SIGPIPE, SIG_IGN);

  TruthTable truth;
  std::string error;
  if (opt.truth.empty()) {
    TruthRow rest;
    rest.range_cm = 500.0;
    rest.range_valid = true;
    truth.set_constant(rest);
  } else if (!truth.load(opt.truth, error)) {
    std::fprintf(stderr, "icgt-sim-device: %s\n", error.c_str());
    return 1;
  }

  std::unique_ptr<HostPort> port;
  if (opt.link.rfind("tcp:", 0) == 0) {
    port = open_tcp_port(static_cast<uint16_t>(std::strtoul(opt.link.c_str() + 4, nullptr, 10)), error);
  } else if (opt.link == "pty" || opt.link.rfind("pty:", 0) == 0) {
    port = open_pty_port(opt.link.size() > 4 ? opt.link.substr(4) : std::string(), error);
  } else {
    usage("--link is pty, pty:PATH or tcp:PORT");
  }
  if (!port) {
    std::fprintf(stderr, "icgt-sim-device: %s\n", error.c_str());
    return 1;
  }

  ClockMap map;
  map.t0_monotonic_ns = opt.t0_monotonic_ns != 0 ? opt.t0_monotonic_ns : icgt::sim::monotonic_now_ns();
  map.device_offset_us = opt.device_offset_us;
  map.device_drift_ppm = opt.device_drift_ppm;

  ImpairedStream link(*port, map, opt.seed);
  link.set_impairment(opt.impairment);

  SimBoardConfig cfg;
  cfg.bno_fitted = opt.imu;
  cfg.bno.seed = opt.seed;
  cfg.bno.noise.gyro_rad_s = 0.002;
  cfg.bno.noise.accel_m_s2 = 0.02;
  cfg.bno.noise.quat = 0.0005;
  cfg.lidar_fitted = opt.lidar;
  cfg.lidar.variant = opt.lidar_model == "v3hp" ? LidarLiteVariant::v3hp : LidarLiteVariant::v3;
  cfg.lidar.noise_sigma_cm = opt.range_noise_cm;
  cfg.lidar.seed = opt.seed + 1;
  cfg.device.lidar_model = opt.lidar_model == "v3hp" ? icgt::proto::LidarModel::v3hp : icgt::proto::LidarModel::v3;
  cfg.feedback_wired = opt.feedback;
  cfg.device.feedback_enabled = opt.feedback;
  cfg.camera = opt.camera;
  cfg.camera.seed = opt.seed + 2;
  cfg.pps_wired = opt.pps;
  cfg.rtc_utc_s_at_boot = opt.rtc_utc_s;
  // An idle Teensy loop turns in microseconds; 20 us keeps the simulated receive stamps as close
  // to arrival as a real board's mostly are, at a modest CPU cost.
  cfg.loop_period_us = 20;
  SimBoard board(cfg, link);
  link.set_device_clock(board.clock());
  {
    std::istringstream misses(opt.camera_miss_triggers);
    std::string item;
    while (std::getline(misses, item, ',')) {
      if (!item.empty()) board.camera().miss_trigger(static_cast<uint32_t>(std::strtoul(item.c_str(), nullptr, 10)));
    }
  }

  ControlSocket control;
  if (!opt.control.empty() && !control.open(opt.control, error)) {
    std::fprintf(stderr, "icgt-sim-device: %s\n", error.c_str());
    return 1;
  }
  EventLog events(opt.events_out);

  std::printf("link: %s\n", port->url().c_str());
  std::fflush(stdout);

  const auto tau_now = [&] { return map.tau_s_at_monotonic(icgt::sim::monotonic_now_ns()); };
  board.clock().set_us(map.device_us_at_tau(tau_now()));
  board.begin();

  std::size_t exposures_emitted = 0;
  std::size_t ignored_emitted = 0;
  uint64_t replug_at_ns = 0;
  int64_t next_pps_utc_s = opt.utc0_us / 1'000'000 + 1;
  const auto handle = [&](const std::string& line) -> std::string {
    std::istringstream in(line);
    std::string cmd;
    in >> cmd;
    if (cmd == "quit") {
      g_stop = 1;
      return "ok";
    }
    if (cmd == "origin") {
      // origin T0_NS DEVICE_OFFSET_US UTC0_US: scenario time starts anew at T0_NS (a session that held
      // its clock until the recorder was up). The caller keeps the device clock and UTC continuous.
      unsigned long long t0 = 0;
      double offset_us = 0.0;
      long long utc0 = 0;
      if (!(in >> t0 >> offset_us >> utc0) || t0 == 0) return "error: origin T0_NS DEVICE_OFFSET_US UTC0_US";
      map.t0_monotonic_ns = t0;
      map.device_offset_us = offset_us;
      link.set_clock_map(map);
      opt.utc0_us = utc0;
      next_pps_utc_s = utc0 / 1'000'000 + 1;
      return "ok";
    }
    if (cmd == "manual_shot") {
      std::string when;
      in >> when;
      if (when == "between") {  // half-way between two triggered exposures (camera_model.hpp)
        board.camera().manual_shot_between_triggers(board.clock().now_us() + 1000);
      } else if (when.empty()) {
        board.camera().manual_shot(board.clock().now_us() + 1000);
      } else {
        return "error: manual_shot [between]";
      }
      return "ok";
    }
    if (cmd == "disconnect") {
      double seconds = 0.0;
      if (!(in >> seconds) || seconds <= 0.0) return "error: disconnect SECONDS";
      link.unplug();
      replug_at_ns = icgt::sim::monotonic_now_ns() + static_cast<uint64_t>(seconds * 1e9);
      events.line(R"({"event":"link","state":"down","tau_s":)" + std::to_string(tau_now()) + "}");
      return "ok";
    }
    if (cmd == "impair") {
      LinkImpairment imp = link.impairment();
      std::string kv;
      while (in >> kv) {
        const auto eq = kv.find('=');
        if (eq == std::string::npos) return "error: impair key=value ...";
        const std::string k = kv.substr(0, eq);
        const double v = std::strtod(kv.c_str() + eq + 1, nullptr);
        if (k == "drop") imp.drop_probability = v;
        else if (k == "flip") imp.flip_probability = v;
        else if (k == "latency_us") imp.frame_us = static_cast<uint32_t>(v);
        else if (k == "jitter_us") imp.jitter_us = static_cast<uint32_t>(v);
        else return "error: unknown impairment " + k;
      }
      link.set_impairment(imp);
      return "ok";
    }
    if (cmd == "i2c") {
      // i2c stuck on|off: a part holds SDA low; i2c stretch ADDR US: the part at ADDR (hex or
      // decimal 7-bit address) holds SCL US microseconds per transfer (0: never).
      std::string what;
      in >> what;
      if (what == "stuck") {
        std::string onoff;
        in >> onoff;
        if (onoff != "on" && onoff != "off") return "error: i2c stuck on|off";
        board.bus().set_stuck(onoff == "on");
        return "ok";
      }
      if (what == "stretch") {
        std::string addr_text;
        long us = -1;
        if (!(in >> addr_text >> us) || us < 0) return "error: i2c stretch ADDR US";
        const long addr = std::strtol(addr_text.c_str(), nullptr, 0);
        if (addr < 0x08 || addr > 0x77) return "error: i2c stretch: address out of range 0x08..0x77";
        board.bus().set_clock_stretch(static_cast<uint8_t>(addr), static_cast<uint32_t>(us));
        return "ok";
      }
      return "error: i2c stuck on|off | i2c stretch ADDR US";
    }
    return "error: unknown command " + cmd;
  };

  while (g_stop == 0) {
    const uint64_t now_ns = icgt::sim::monotonic_now_ns();
    const double tau = map.tau_s_at_monotonic(now_ns);
    const TruthRow r = truth.at(tau);
    Bno055Truth t;
    t.quat_wxyz = r.quat_wxyz;
    t.gyro_rad_s = r.gyro_rad_s;
    t.accel_m_s2 = r.accel_m_s2;
    t.lin_accel_m_s2 = r.lin_accel_m_s2;
    board.bno().set_truth(t);
    board.lidar().set_range_cm(r.range_cm);
    board.lidar().set_no_signal(!r.range_valid);
    if (opt.pps) {
      const double tau_pps = (static_cast<double>(next_pps_utc_s) * 1e6 - static_cast<double>(opt.utc0_us)) * 1e-6;
      if (tau_pps < tau + 0.5) {
        board.pps_pulse(map.device_us_at_tau(tau_pps));
        ++next_pps_utc_s;
      }
    }
    link.pump(now_ns);
    // Run the board up to the time *after* taking in the host's bytes: with the loop-start time
    // the bytes would wait a whole loop iteration in virtual time and the reply would leave that
    // much later in real time than its device stamp says (a path asymmetry the host cannot see).
    board.run_until(map.device_us_at_tau(map.tau_s_at_monotonic(icgt::sim::monotonic_now_ns())));
    link.pump(icgt::sim::monotonic_now_ns());

    const auto& ex = board.camera().exposures();
    for (; exposures_emitted < ex.size(); ++exposures_emitted) events.line(exposure_json(ex[exposures_emitted]));
    const auto& ig = board.camera().ignored();
    for (; ignored_emitted < ig.size(); ++ignored_emitted) events.line(ignored_json(ig[ignored_emitted]));
    control.poll(handle);
    board.camera().release_held_manual_shot(board.clock().now_us());
    if (replug_at_ns != 0 && icgt::sim::monotonic_now_ns() >= replug_at_ns) {
      link.replug();
      replug_at_ns = 0;
      events.line(R"({"event":"link","state":"up","tau_s":)" + std::to_string(tau_now()) + "}");
    }
    wait_for_host_or_due_bytes(link, *port);
  }
  const auto& c = link.counters();
  std::fprintf(stderr, "icgt-sim-device: stopped; %llu bytes to host, %llu to device, %llu dropped, %llu flipped\n",
               static_cast<unsigned long long>(c.bytes_to_host), static_cast<unsigned long long>(c.bytes_to_device),
               static_cast<unsigned long long>(c.dropped), static_cast<unsigned long long>(c.flipped));
  return 0;
}
