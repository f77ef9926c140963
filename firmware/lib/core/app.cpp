#include "core/app.hpp"

#include <cstring>

namespace icgt::core {
namespace {

using proto::ErrorCode;

Bno055Config imu_config(const DeviceConfig& c) {
  Bno055Config b;
  b.opr_mode = c.imu_mode;
  b.ext_crystal = c.imu_ext_crystal;
  b.rate_hz = c.imu_rate_hz == 0 ? 1 : c.imu_rate_hz;
  return b;
}

LidarLiteConfig lidar_config(const DeviceConfig& c) {
  LidarLiteConfig l;
  l.model = c.lidar_model == proto::LidarModel::v3hp ? LidarModelKind::v3hp : LidarModelKind::v3;
  l.preset = c.lidar_preset;
  l.rate_hz = c.range_rate_hz == 0 ? 1 : c.range_rate_hz;
  l.bias_every = c.lidar_bias_every;
  return l;
}

// interval_us 0: no capture (or a single shot) to derive an automatic timeout from.
FeedbackConfig feedback_config(const DeviceConfig& c, bool wired, uint32_t interval_us = 0) {
  FeedbackConfig f;
  f.enabled = c.feedback_enabled && wired;
  f.active_high = (c.polarity & proto::PinPolarity::feedback_active_high) != 0;
  f.min_lag_us = c.feedback_min_lag_us;
  f.timeout_us = c.feedback_timeout_us != 0
                     ? c.feedback_timeout_us
                     : limits::auto_feedback_timeout_us(c.feedback_min_lag_us, interval_us, interval_us == 0);
  return f;
}

ErrorCode refuse(proto::Limit& limit, proto::Limit which, ErrorCode code = ErrorCode::out_of_range) {
  limit = which;
  return code;
}

LinePolarity line_polarity(uint8_t polarity) {
  LinePolarity p;
  p.focus_active_high = (polarity & proto::PinPolarity::focus_active_high) != 0;
  p.shutter_active_high = (polarity & proto::PinPolarity::shutter_active_high) != 0;
  return p;
}

// Bounded text building for LOG without printf (newlib's printf alone would cost more
// flash than the whole core).
struct Text {
  char buf[sizeof(proto::Log::text)]{};
  uint8_t len = 0;

  void add(const char* s) {
    while (*s != '\0' && len < sizeof buf) buf[len++] = *s++;
  }
  void add_u32(uint32_t v) {
    char digits[10];
    int n = 0;
    do {
      digits[n++] = static_cast<char>('0' + v % 10);
      v /= 10;
    } while (v != 0);
    while (n > 0 && len < sizeof buf) buf[len++] = digits[--n];
  }
};

const char* imu_state_text(Bno055State s) {
  switch (s) {
    case Bno055State::absent: return "BNO055 not answering at its address; retrying with back-off";
    case Bno055State::initialising: return "BNO055 initialising";
    case Bno055State::running: return "BNO055 running";
    case Bno055State::backing_off: return "BNO055 failed (NACK or reset); re-initialising after back-off";
  }
  return "BNO055 state unknown";
}

const char* lidar_state_text(LidarState s) {
  switch (s) {
    case LidarState::disabled: return "LIDAR-Lite disabled: invalid configuration";
    case LidarState::absent: return "LIDAR-Lite not answering at its address; retrying with back-off";
    case LidarState::configuring: return "LIDAR-Lite configuring";
    case LidarState::running: return "LIDAR-Lite running";
    case LidarState::backing_off: return "LIDAR-Lite failed (NACK or busy timeout); re-configuring after back-off";
  }
  return "LIDAR-Lite state unknown";
}

}  // namespace

App::App(const AppPorts& ports, const BoardIdentity& identity, const DeviceConfig& config)
    : ports_(ports),
      identity_(identity),
      config_(config),
      trigger_(ports.trigger_alarm, ports.clock, ports.shutter, ports.focus, line_polarity(config.polarity)),
      pairing_(trigger_.records(), ports.feedback),
      timebase_(ports.rtc, ports.pps),
      imu_(ports.i2c, ports.clock, imu_config(config)),
      lidar_(ports.i2c, ports.clock, lidar_config(config)),
      imu_enabled_(config.imu_rate_hz != 0),
      lidar_enabled_(config.range_rate_hz != 0 && config.lidar_model != proto::LidarModel::none) {}

void App::begin() {
  const uint64_t now = ports_.clock.now_us();
  timebase_.begin(now);
  if (ports_.pps != nullptr) {
    (void)timebase_.start_pps((config_.polarity & proto::PinPolarity::pps_rising) != 0);
  }
  const FeedbackResult fb = pairing_.configure(feedback_config(config_, ports_.feedback != nullptr));
  if (fb != FeedbackResult::ok) log(now, proto::LogLevel::warning, "feedback line could not be attached");
  next_status_t_us_ = now;
  link_up_ = ports_.link.connected();
  if (link_up_) send_after_t_us_ = now + kLinkSettleUs;
  send_hello(now);
}

void App::poll() {
  const uint64_t start = ports_.clock.now_us();
  const bool up = ports_.link.connected();
  if (up && !link_up_) {
    send_hello(start);  // a host (re)opened the port: tell it who we are, once it is listening
    send_after_t_us_ = start + kLinkSettleUs;
  }
  if (!up && link_up_) {
    outbox_.link_lost();
    time_sync_.clear();
  }
  link_up_ = up;

  receive(start);
  watch_capture(ports_.clock.now_us());
  time_sync_.release_due(ports_.clock.now_us(), outbox_);
  timebase_.poll(start);
  drain_exposures(start);
  drain_pps();
  step_sensors(ports_.clock.now_us());
  release_exposures(ports_.clock.now_us());
  report_sensor_states(ports_.clock.now_us());

  const uint64_t now = ports_.clock.now_us();
  if (now >= next_status_t_us_) {
    (void)outbox_.push(status(now));  // a full event queue counts the drop itself
    loop_max_us_ = 0;
    next_status_t_us_ += kStatusPeriodUs;
    if (next_status_t_us_ <= now) next_status_t_us_ = now + kStatusPeriodUs;  // after a long stall
  }
  if (link_up_ && start >= send_after_t_us_) outbox_.pump(ports_.link, ports_.clock.now_us());
  // No host: frames still get their sequence numbers and go into the history, for RESEND.
  if (!link_up_) outbox_.discard(ports_.clock.now_us());

  const uint64_t took = ports_.clock.now_us() - start;
  if (took > loop_max_us_) loop_max_us_ = took > UINT32_MAX ? UINT32_MAX : static_cast<uint32_t>(took);
}

void App::receive(uint64_t now_us) {
  uint8_t buf[kRxChunkBytes];
  const std::size_t n = ports_.link.read(buf, sizeof buf);
  // The whole chunk arrived by now_us (read just now): that is the receive time of every
  // frame it completes. The loop runs far faster than the host sends commands.
  for (std::size_t i = 0; i < n; ++i) {
    switch (rx_.push(buf[i])) {
      case proto::StreamDecoder::Status::frame:
        watchdog_.heard(now_us);  // any valid frame: the host is alive
        on_frame(now_us);
        break;
      case proto::StreamDecoder::Status::rejected: on_rejected_frame(); break;
      case proto::StreamDecoder::Status::pending: break;
    }
  }
}

void App::on_rejected_frame() {
  // Only frames whose CRC passed have a header worth answering.
  switch (rx_.last_reject()) {
    case proto::Reject::unknown_type: ack(ErrorCode::unknown_command); break;
    case proto::Reject::bad_length: ack(ErrorCode::bad_length, static_cast<uint32_t>(rx_.body_len())); break;
    default: break;
  }
}

void App::ack(ErrorCode code, uint32_t detail) {
  proto::Ack a;
  a.request_seq = rx_.header().seq;
  a.request_type = rx_.header().type;
  a.error_code = static_cast<uint8_t>(code);
  a.detail = detail;
  (void)outbox_.push(a);
}

void App::on_frame(uint64_t rx_t_us) {
  switch (static_cast<proto::MsgId>(rx_.header().type)) {
    case proto::MsgId::START_CAPTURE: {
      proto::StartCapture cmd;
      proto::Limit limit = proto::Limit::none;
      if (rx_.decode(cmd)) {
        const ErrorCode r = start_capture(cmd, rx_t_us, limit);
        ack(r, static_cast<uint32_t>(limit));
      }
      return;
    }
    case proto::MsgId::STOP_CAPTURE: {
      proto::StopCapture cmd;
      if (!rx_.decode(cmd)) return;
      const TriggerResult r = cmd.camera_id != 0 ? TriggerResult::out_of_range : trigger_.stop();
      ack(static_cast<ErrorCode>(r), cmd.camera_id != 0 ? static_cast<uint32_t>(proto::Limit::camera_id) : 0);
      if (r == TriggerResult::ok) {
        end_capture(proto::StopCause::host, rx_t_us);
        log(rx_t_us, proto::LogLevel::info, "capture stopped by host");
      }
      return;
    }
    case proto::MsgId::CONFIGURE: {
      proto::Configure cmd;
      proto::Limit limit = proto::Limit::none;
      if (rx_.decode(cmd)) {
        const ErrorCode r = configure(cmd, limit);
        ack(r, static_cast<uint32_t>(limit));
      }
      return;
    }
    case proto::MsgId::TIME_SYNC: {
      proto::TimeSync req;
      if (!rx_.decode(req)) return;
      proto::TimeSyncReply reply;
      reply.host_t_ns = req.host_t_ns;
      reply.request_seq = rx_.header().seq;
      reply.device_rx_t_us = rx_t_us;
      time_sync_.hold(reply, rx_t_us, outbox_);  // device_tx_t_us is filled when the frame is built
      return;
    }
    case proto::MsgId::SET_TIME: {
      proto::SetTime cmd;
      if (!rx_.decode(cmd)) return;
      const SetTimeResult r = timebase_.set_time(cmd.utc_us, rx_t_us);
      ack(static_cast<ErrorCode>(r));
      return;
    }
    case proto::MsgId::PING: {
      proto::Ping ping;
      if (!rx_.decode(ping)) return;
      ack(ErrorCode::ok, ping.nonce);
      if (ping.nonce == 0) send_hello(rx_t_us);
      return;
    }
    case proto::MsgId::RESEND: {
      proto::Resend cmd;
      if (!rx_.decode(cmd)) return;
      if (cmd.count == 0) {
        ack(ErrorCode::out_of_range, 0);
      } else if (!outbox_.request_resend(cmd.first_seq, cmd.count)) {
        ack(ErrorCode::out_of_range, static_cast<uint32_t>(Outbox::kResendQueue));  // too many waiting
      } else {
        ack(ErrorCode::ok, cmd.count);  // queued before the frames: the ACK comes first
      }
      return;
    }
    case proto::MsgId::HOST_RECEIVED: {
      proto::HostReceived cmd;
      if (!rx_.decode(cmd)) return;
      host_received_seq_ = cmd.next_seq;
      host_received_valid_ = true;
      recording_id_ = cmd.recording_id;
      ack(ErrorCode::ok, cmd.next_seq);
      return;
    }
    default:
      ack(ErrorCode::unknown_command);  // a device-to-host type sent to the device
      return;
  }
}

ErrorCode App::start_capture(const proto::StartCapture& cmd, uint64_t now_us, proto::Limit& limit) {
  limit = proto::Limit::none;
  if (trigger_.state() == CaptureState::capturing) return ErrorCode::busy_capturing;
  if (cmd.camera_id != 0) return refuse(limit, proto::Limit::camera_id);  // one camera port on every board so far
  CaptureParams p;
  p.mode = static_cast<CaptureMode>(cmd.mode);
  p.camera_id = cmd.camera_id;
  p.interval_us = cmd.interval_us;
  p.count = cmd.count;
  p.focus_lead_us = cmd.focus_lead_us;
  p.burst_us = cmd.burst_us;
  p.shutter_pulse_us = cmd.shutter_pulse_us;
  const proto::Limit broken = Trigger::check(p);
  if (broken != proto::Limit::none) return refuse(limit, broken);
  if (!HostWatchdog::valid(cmd.host_timeout_ms)) return refuse(limit, proto::Limit::host_timeout);
  // Pairing is first-in-first-out: it is only unambiguous while the window a feedback edge may
  // arrive in (min lag .. timeout after its trigger) is shorter than the interval. A longer one
  // would let one missed exposure shift every later pair.
  const bool single = p.mode == CaptureMode::single;
  const FeedbackConfig fb = feedback_config(config_, ports_.feedback != nullptr, single ? 0 : p.interval_us);
  if (fb.enabled && (fb.timeout_us <= fb.min_lag_us || (!single && fb.timeout_us - fb.min_lag_us >= p.interval_us))) {
    return refuse(limit, proto::Limit::feedback_window);
  }
  if (pairing_.configure(fb) != FeedbackResult::ok) return refuse(limit, proto::Limit::feedback_timeout);
  const TriggerResult r = trigger_.start(p, now_us);
  if (r == TriggerResult::ok) {
    capture_ = cmd;
    capture_start_seq_ = outbox_.next_seq() + static_cast<uint32_t>(outbox_.queued()) + 1;  // after the ACK
    watchdog_.arm(cmd.host_timeout_ms, now_us);
    capture_running_ = true;
    stop_cause_ = proto::StopCause::none;
    stopped_t_us_ = 0;
    log(now_us, proto::LogLevel::info, "capture started, mode ", cmd.mode, true);
  }
  return static_cast<ErrorCode>(r);
}

ErrorCode App::configure(const proto::Configure& cmd, proto::Limit& limit) {
  limit = proto::Limit::none;
  if (trigger_.state() == CaptureState::capturing) return ErrorCode::busy_capturing;
  DeviceConfig next;
  next.imu_rate_hz = cmd.imu_rate_hz;
  next.imu_mode = cmd.imu_mode;
  next.imu_ext_crystal = cmd.imu_ext_crystal != 0;
  next.range_rate_hz = cmd.range_rate_hz;
  next.lidar_model = static_cast<proto::LidarModel>(cmd.lidar_model);
  next.lidar_preset = cmd.lidar_preset;
  next.lidar_bias_every = cmd.lidar_bias_every;
  next.polarity = cmd.polarity;
  next.feedback_enabled = cmd.feedback_enabled != 0;
  next.feedback_timeout_us = cmd.feedback_timeout_us;
  next.feedback_min_lag_us = cmd.feedback_min_lag_us;

  // Validate everything before touching anything: a refused CONFIGURE changes nothing.
  const bool want_imu = next.imu_rate_hz != 0;
  const bool want_lidar = next.range_rate_hz != 0 && next.lidar_model != proto::LidarModel::none;
  if (cmd.imu_ext_crystal > 1 || cmd.feedback_enabled > 1) return refuse(limit, proto::Limit::flag_value);
  if (next.lidar_model != proto::LidarModel::none && next.lidar_model != proto::LidarModel::v3 &&
      next.lidar_model != proto::LidarModel::v3hp) {
    return refuse(limit, proto::Limit::lidar_model);
  }
  if (want_imu && !Bno055::valid(imu_config(next))) {
    return refuse(limit, next.imu_rate_hz > limits::kImuMaxRateHz ? proto::Limit::imu_rate : proto::Limit::imu_mode);
  }
  if (want_lidar && !LidarLite::valid(lidar_config(next))) {
    if (next.range_rate_hz > limits::kLidarMaxRateHz) return refuse(limit, proto::Limit::range_rate);
    return refuse(limit, next.lidar_bias_every == 0 ? proto::Limit::lidar_bias_every : proto::Limit::lidar_preset);
  }
  if (next.feedback_timeout_us != 0 && (next.feedback_timeout_us < ExposurePairing::kMinTimeoutUs ||
                                        next.feedback_timeout_us > ExposurePairing::kMaxTimeoutUs)) {
    return refuse(limit, proto::Limit::feedback_timeout);
  }
  if (next.feedback_min_lag_us > ExposurePairing::kMaxMinLagUs ||
      (next.feedback_timeout_us != 0 && next.feedback_min_lag_us >= next.feedback_timeout_us)) {
    return refuse(limit, proto::Limit::feedback_min_lag);
  }
  if (next.feedback_enabled && ports_.feedback == nullptr) {
    return refuse(limit, proto::Limit::feedback_line_missing, ErrorCode::sensor_missing);
  }
  if (want_imu && imu_.state() == Bno055State::absent) {
    return refuse(limit, proto::Limit::imu_missing, ErrorCode::sensor_missing);
  }
  if (want_lidar && lidar_.state() == LidarState::absent) {
    return refuse(limit, proto::Limit::lidar_missing, ErrorCode::sensor_missing);
  }

  if (pairing_.configure(feedback_config(next, ports_.feedback != nullptr)) != FeedbackResult::ok) {
    // the line exists but cannot interrupt: nothing changed yet
    return refuse(limit, proto::Limit::feedback_line_missing, ErrorCode::sensor_missing);
  }
  (void)trigger_.set_polarity(line_polarity(next.polarity));  // cannot fail: not capturing
  if (ports_.pps != nullptr) timebase_.set_pps_rising((next.polarity & proto::PinPolarity::pps_rising) != 0);
  if (want_imu) (void)imu_.reconfigure(imu_config(next));        // validated above
  if (want_lidar) (void)lidar_.reconfigure(lidar_config(next));  // validated above
  imu_enabled_ = want_imu;
  lidar_enabled_ = want_lidar;
  config_ = next;
  return ErrorCode::ok;
}

void App::watch_capture(uint64_t now_us) {
  if (!capture_running_) return;
  if (trigger_.state() != CaptureState::capturing) {
    end_capture(proto::StopCause::done, now_us);  // single or count ran out
    return;
  }
  if (!watchdog_.expired(now_us)) return;
  // The shot schedule may have run out in the alarm interrupt since the state was read: then it is done.
  const bool stopped = trigger_.stop() == TriggerResult::ok;
  end_capture(stopped ? proto::StopCause::host_silent : proto::StopCause::done, now_us);
  if (stopped) {
    log(now_us, proto::LogLevel::warning, "capture stopped by the device: no frame from the host for ms ",
        watchdog_.timeout_ms(), true);
  }
}

void App::end_capture(proto::StopCause cause, uint64_t now_us) {
  capture_running_ = false;
  watchdog_.disarm();
  stop_cause_ = cause;
  stopped_t_us_ = now_us;
}

bool App::i2c_credit_left(uint64_t now_us) {
  if (now_us > i2c_credit_t_us_) {
    const uint64_t dt = now_us - i2c_credit_t_us_;
    const uint64_t grow = (dt > INT32_MAX ? uint64_t{INT32_MAX} : dt) * kI2cSharePercent / 100;
    const int64_t credit = i2c_credit_us_ + static_cast<int64_t>(grow);
    i2c_credit_us_ = credit > static_cast<int64_t>(kI2cBurstUs) ? static_cast<int64_t>(kI2cBurstUs) : credit;
    i2c_credit_t_us_ = now_us;
  }
  if (i2c_credit_us_ > 0) return true;
  ++i2c_deferred_steps_;
  return false;
}

void App::spend_i2c(uint64_t from_us) {
  const uint64_t took = ports_.clock.now_us() - from_us;
  i2c_busy_us_ += took;
  i2c_credit_us_ -= static_cast<int64_t>(took > INT32_MAX ? INT32_MAX : took);
}

void App::step_sensors(uint64_t now_us) {
  const bool imu_go = imu_enabled_ && i2c_credit_left(now_us);
  const Bno055Step imu_step = imu_go ? imu_.step(now_us) : Bno055Step::idle;
  if (imu_go) spend_i2c(now_us);
  if (imu_step == Bno055Step::sample_ready) {
    const ImuSample& s = imu_.sample();
    proto::Imu m;
    m.read_start_t_us = s.read_start_t_us;
    m.read_end_t_us = s.read_end_t_us;
    m.quat_w = s.quat_w;
    m.quat_x = s.quat_x;
    m.quat_y = s.quat_y;
    m.quat_z = s.quat_z;
    m.gyro_x_rad_s = s.gyro_x_rad_s;
    m.gyro_y_rad_s = s.gyro_y_rad_s;
    m.gyro_z_rad_s = s.gyro_z_rad_s;
    m.accel_x_m_s2 = s.accel_x_m_s2;
    m.accel_y_m_s2 = s.accel_y_m_s2;
    m.accel_z_m_s2 = s.accel_z_m_s2;
    m.lin_accel_x_m_s2 = s.lin_accel_x_m_s2;
    m.lin_accel_y_m_s2 = s.lin_accel_y_m_s2;
    m.lin_accel_z_m_s2 = s.lin_accel_z_m_s2;
    m.calib_stat = s.calib_stat;
    m.flags = static_cast<uint8_t>(proto::ImuFlags::fusion_running |
                                   (s.reinitialised ? proto::ImuFlags::reinitialised : 0u));
    (void)outbox_.push(m);  // shed when full, counted as dropped_imu
    snapshot_.add_imu(s);
  }
  const uint64_t lidar_t_us = ports_.clock.now_us();
  const bool lidar_go = lidar_enabled_ && i2c_credit_left(lidar_t_us);
  const LidarStep lidar_step = lidar_go ? lidar_.step(lidar_t_us) : LidarStep::idle;
  if (lidar_go) spend_i2c(lidar_t_us);
  if (lidar_step == LidarStep::sample_ready) {
    const RangeSample& s = lidar_.sample();
    proto::Range m;
    m.acq_start_t_us = s.acq_start_t_us;
    m.read_t_us = s.read_t_us;
    m.distance_cm = s.valid ? s.distance_cm : 0;
    m.signal_strength = s.signal_strength;
    uint32_t flags = 0;
    if (s.valid) flags |= proto::RangeFlags::valid;
    if (s.bias_corrected) flags |= proto::RangeFlags::bias_corrected;
    if (s.no_signal) flags |= proto::RangeFlags::no_signal;
    if (s.timeout) flags |= proto::RangeFlags::timeout;
    if (s.i2c_error) flags |= proto::RangeFlags::i2c_error;
    m.flags = static_cast<uint8_t>(flags);
    (void)outbox_.push(m);  // shed when full, counted as dropped_range
    snapshot_.add_range(s);
  }
}

void App::drain_exposures(uint64_t now_us) {
  Exposure out[8];
  std::size_t n;
  do {
    n = pairing_.poll(now_us, out, 8);
    for (std::size_t i = 0; i < n; ++i) {
      proto::Exposure m;
      m.image_index = out[i].image_index;
      m.camera_id = out[i].camera_id;
      m.flags = out[i].flags;
      m.trigger_t_us = out[i].trigger_t_us;
      m.feedback_start_t_us = out[i].feedback_start_t_us;
      m.feedback_end_t_us = out[i].feedback_end_t_us;
      m.duration_us = out[i].duration_us;
      // Mid-exposure as the host computes it (icgt.geotag.geotagger.Geotagger.add_exposure).
      uint64_t mid_us = m.trigger_t_us;
      if (m.feedback_start_t_us != 0) {
        mid_us = m.feedback_start_t_us;
        if (m.feedback_end_t_us != 0) mid_us += (m.feedback_end_t_us - m.feedback_start_t_us) / 2;
      }
      release_exposures(now_us);
      if (held_count_ == kHeldExposures) send_held_front();  // never expected: 8 shots within 50 ms
      held_[(held_head_ + held_count_) % kHeldExposures] = HeldExposure{m, mid_us};
      ++held_count_;
    }
  } while (n == 8);
  release_exposures(now_us);
}

void App::release_exposures(uint64_t now_us) {
  while (held_count_ > 0 && snapshot_.settled(held_[held_head_].mid_us, now_us, lidar_enabled_, imu_enabled_)) {
    send_held_front();
  }
}

void App::send_held_front() {
  HeldExposure& h = held_[held_head_];
  const Snapshot s = snapshot_.at(h.mid_us);
  h.msg.snapshot_flags = s.flags;
  h.msg.range_mm = s.range_mm;
  h.msg.range_age_us = s.range_age_us;
  h.msg.imu_age_us = s.imu_age_us;
  h.msg.imu_calib_stat = s.imu_calib_stat;
  h.msg.quat_w_q14 = s.quat_q14[0];
  h.msg.quat_x_q14 = s.quat_q14[1];
  h.msg.quat_y_q14 = s.quat_q14[2];
  h.msg.quat_z_q14 = s.quat_q14[3];
  h.msg.gyro_x_rad900 = s.gyro_rad900[0];
  h.msg.gyro_y_rad900 = s.gyro_rad900[1];
  h.msg.gyro_z_rad900 = s.gyro_rad900[2];
  (void)outbox_.push(h.msg);  // the event queue is never shed; a full one counts dropped_event
  held_head_ = (held_head_ + 1) % kHeldExposures;
  --held_count_;
}

void App::drain_pps() {
  PpsEdge e;
  while (timebase_.pop_pps(e)) {
    proto::Pps m;
    m.t_us = e.t_us;
    m.pps_count = e.count;
    (void)outbox_.push(m);
  }
}

void App::report_sensor_states(uint64_t now_us) {
  if (imu_enabled_ && imu_.state() != last_imu_state_) {
    last_imu_state_ = imu_.state();
    const bool bad = last_imu_state_ == Bno055State::absent || last_imu_state_ == Bno055State::backing_off;
    log(now_us, bad ? proto::LogLevel::warning : proto::LogLevel::info, imu_state_text(last_imu_state_));
  }
  if (lidar_enabled_ && lidar_.state() != last_lidar_state_) {
    last_lidar_state_ = lidar_.state();
    const bool bad = last_lidar_state_ != LidarState::configuring && last_lidar_state_ != LidarState::running;
    log(now_us, bad ? proto::LogLevel::warning : proto::LogLevel::info, lidar_state_text(last_lidar_state_));
  }
}

proto::Status App::status(uint64_t now_us) {
  proto::Status s;
  s.t_us = now_us;
  s.capture_state = static_cast<uint8_t>(trigger_.state());
  uint32_t health = 0;
  if (imu_enabled_ && imu_.present()) health |= proto::SensorHealth::imu_present;
  if (imu_enabled_ && imu_.running()) health |= proto::SensorHealth::imu_ok;
  if (lidar_enabled_ && lidar_.present()) health |= proto::SensorHealth::lidar_present;
  if (lidar_enabled_ && lidar_.running()) health |= proto::SensorHealth::lidar_ok;
  if (pairing_.feedback_enabled()) health |= proto::SensorHealth::feedback_configured;
  if (timebase_.pps_locked()) health |= proto::SensorHealth::pps_locked;
  if (timebase_.rtc_set()) health |= proto::SensorHealth::rtc_set;
  s.sensor_health = static_cast<uint8_t>(health);
  s.triggers_fired = trigger_.triggers_fired();
  s.exposures_confirmed = pairing_.exposures_confirmed();
  s.feedback_missing = pairing_.feedback_missing();
  s.feedback_unsolicited = pairing_.feedback_unsolicited();
  const OutboxCounters c = outbox_.counters();
  s.messages_sent = c.messages_sent;
  s.dropped_imu = c.dropped_imu;
  s.dropped_range = c.dropped_range;
  s.dropped_log = c.dropped_log;
  // Trigger records lost between the interrupt and the loop are exposures lost too.
  s.dropped_event = c.dropped_event + trigger_.records().dropped();
  s.i2c_errors = imu_.i2c_errors() + lidar_.i2c_errors();
  s.imu_reinits = imu_.reinits();
  s.lidar_reinits = lidar_.reinits();
  s.rx_frames_ok = rx_.stats().frames_ok;
  s.rx_frames_rejected = rx_.stats().rejected();
  s.rx_seq_missed = rx_.stats().seq_missed;
  s.loop_max_us = loop_max_us_;
  return s;
}

void App::send_hello(uint64_t now_us) {
  proto::Hello h;
  h.protocol_version = proto::kProtocolVersion;
  h.table_hash = proto::kTableHash;
  h.t_us = now_us;
  const std::size_t len = proto::wire::strnlen_bounded(identity_.firmware_version, sizeof h.firmware_version);
  std::memcpy(h.firmware_version, identity_.firmware_version, len);
  h.board = static_cast<uint8_t>(identity_.board);
  h.serial_number = identity_.serial_number;
  h.clock_source = static_cast<uint8_t>(timebase_.clock_source());
  h.rtc_utc_us_at_boot = timebase_.utc_us_at_boot();
  h.lidar_model = static_cast<uint8_t>(lidar_enabled_ ? config_.lidar_model : proto::LidarModel::none);
  (void)outbox_.push(h);
  (void)outbox_.push(device_state(now_us));
}

proto::DeviceState App::device_state(uint64_t now_us) const {
  proto::DeviceState d;
  d.t_us = now_us;
  d.capture_state = static_cast<uint8_t>(trigger_.state());
  d.mode = capture_.mode;
  d.interval_us = capture_.interval_us;
  d.count = capture_.count;
  d.focus_lead_us = capture_.focus_lead_us;
  d.burst_us = capture_.burst_us;
  d.shutter_pulse_us = capture_.shutter_pulse_us;
  d.triggers_fired = trigger_.triggers_fired();
  d.capture_start_seq = capture_start_seq_;
  d.next_seq = outbox_.next_seq();
  d.history_first_seq = outbox_.history().first_known_seq();
  d.host_received_seq = host_received_seq_;
  d.host_received_valid = host_received_valid_ ? 1 : 0;
  d.imu_rate_hz = imu_enabled_ ? config_.imu_rate_hz : 0;
  d.range_rate_hz = lidar_enabled_ ? config_.range_rate_hz : 0;
  d.lidar_model = static_cast<uint8_t>(lidar_enabled_ ? config_.lidar_model : proto::LidarModel::none);
  d.polarity = config_.polarity;
  d.feedback_enabled = pairing_.feedback_enabled() ? 1 : 0;
  d.feedback_timeout_us = config_.feedback_timeout_us;
  d.host_timeout_ms = capture_.host_timeout_ms;
  d.stop_cause = static_cast<uint8_t>(stop_cause_);
  d.stopped_t_us = stopped_t_us_;
  d.recording_id = recording_id_;
  return d;
}

void App::log(uint64_t now_us, proto::LogLevel level, const char* text, uint32_t number, bool with_number) {
  Text t;
  t.add(text);
  if (with_number) t.add_u32(number);
  proto::Log m;
  m.t_us = now_us;
  m.level = static_cast<uint8_t>(level);
  std::memcpy(m.text, t.buf, t.len);
  m.text_len = t.len;
  (void)outbox_.push(m);  // shed when full, counted as dropped_log
}

}  // namespace icgt::core
