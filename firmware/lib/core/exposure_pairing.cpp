#include "core/exposure_pairing.hpp"

#include "protocol/messages.hpp"

namespace icgt::core {

static_assert(exposure_flags::feedback_missing == proto::ExposureFlags::feedback_missing);
static_assert(exposure_flags::no_feedback_line == proto::ExposureFlags::no_feedback_line);
static_assert(exposure_flags::unsolicited == proto::ExposureFlags::unsolicited);
static_assert(exposure_flags::end_missing == proto::ExposureFlags::end_missing);
static_assert(exposure_flags::focus_cycle == proto::ExposureFlags::focus_cycle);
static_assert(static_cast<uint8_t>(FeedbackResult::ok) == static_cast<uint8_t>(proto::ErrorCode::ok));
static_assert(static_cast<uint8_t>(FeedbackResult::out_of_range) ==
              static_cast<uint8_t>(proto::ErrorCode::out_of_range));
static_assert(static_cast<uint8_t>(FeedbackResult::not_supported) ==
              static_cast<uint8_t>(proto::ErrorCode::not_supported));

ExposurePairing::ExposurePairing(TriggerQueue& triggers, hal::EdgeInput* feedback, uint8_t camera_id)
    : triggers_(triggers), line_(feedback), camera_id_(camera_id) {}

ExposurePairing::~ExposurePairing() {
  if (attached_) line_->detach();
}

FeedbackResult ExposurePairing::configure(const FeedbackConfig& config) {
  if (config.timeout_us < kMinTimeoutUs || config.timeout_us > kMaxTimeoutUs || config.end_timeout_us == 0 ||
      config.min_lag_us > kMaxMinLagUs || config.min_lag_us >= config.timeout_us) {
    return FeedbackResult::out_of_range;
  }
  if (config.enabled) {
    if (line_ == nullptr) return FeedbackResult::not_supported;
    if (!attached_) {
      if (!line_->attach(&ExposurePairing::on_feedback_edge, this)) return FeedbackResult::not_supported;
      attached_ = true;
    }
  } else if (attached_) {
    line_->detach();
    attached_ = false;
  }
  config_ = config;
  return FeedbackResult::ok;
}

void ExposurePairing::on_feedback_edge(void* ctx, bool level_high, uint64_t t_us) {
  auto* self = static_cast<ExposurePairing*>(ctx);
  FeedbackEdge edge;
  edge.t_us = t_us;
  edge.level_high = level_high;
  (void)self->edges_.push(edge);  // a full queue counts the drop; pairing degrades to flags
}

void ExposurePairing::pull_triggers() {
  TriggerRecord record;
  while (pending_count_ < kPendingCapacity && triggers_.pop(record)) {
    pending_[(pending_head_ + pending_count_) % kPendingCapacity] = record;
    ++pending_count_;
  }
}

void ExposurePairing::pending_pop() {
  pending_head_ = (pending_head_ + 1) % kPendingCapacity;
  --pending_count_;
}

Exposure ExposurePairing::from_trigger(const TriggerRecord& record, uint8_t flags) const {
  Exposure x;
  x.image_index = record.image_index;
  x.camera_id = record.camera_id;
  x.flags = static_cast<uint8_t>(record.flags | flags);
  x.trigger_t_us = record.trigger_t_us;
  return x;
}

Exposure ExposurePairing::open_record(uint8_t extra_flags) const {
  Exposure x;
  if (open_solicited_) {
    x = from_trigger(open_trigger_, extra_flags);
  } else {
    x.camera_id = camera_id_;
    x.flags = static_cast<uint8_t>(exposure_flags::unsolicited | extra_flags);
  }
  x.feedback_start_t_us = open_start_t_us_;
  return x;
}

std::size_t ExposurePairing::poll(uint64_t now_us, Exposure* out, std::size_t out_cap) {
  std::size_t n = 0;
  if (!config_.enabled) {
    // Edges left over from before the line was disabled describe nothing we can pair.
    FeedbackEdge stale;
    while (edges_.pop(stale)) {
    }
    have_edge_ = false;
  }

  // Each pass either emits one record or consumes one edge, so this ends.
  while (n < out_cap) {
    pull_triggers();

    if (!config_.enabled) {
      if (open_) {
        out[n++] = open_record(exposure_flags::end_missing);
        ++end_missing_;
        open_ = false;
        continue;
      }
      if (pending_count_ == 0) break;
      out[n++] = from_trigger(pending_front(), exposure_flags::no_feedback_line);
      pending_pop();
      continue;
    }

    if (!have_edge_ && edges_.pop(edge_)) {
      have_edge_ = true;
      // Every trigger fired before this edge was queued before it: pull them now so the
      // edge is never taken for a manual shot just because its trigger was still queued.
      pull_triggers();
    }

    // Nothing earlier than the horizon can still arrive: edges are queued in time order,
    // and with the queue empty every edge up to now_us has already been queued.
    const uint64_t horizon_us = have_edge_ ? edge_.t_us : now_us;

    if (open_ && open_start_t_us_ + config_.end_timeout_us < horizon_us) {
      out[n++] = open_record(exposure_flags::end_missing);
      ++end_missing_;
      open_ = false;
      continue;
    }
    if (pending_count_ > 0 && pending_front().trigger_t_us + config_.timeout_us < horizon_us) {
      out[n++] = from_trigger(pending_front(), exposure_flags::feedback_missing);
      ++feedback_missing_;
      pending_pop();
      continue;
    }
    if (!have_edge_) break;

    const bool active = edge_.level_high == config_.active_high;
    if (active) {
      if (open_) {
        // A second start before an end: the end edge was lost. Close the first, keep the
        // edge for the next pass.
        out[n++] = open_record(exposure_flags::end_missing);
        ++end_missing_;
        open_ = false;
        continue;
      }
      if (pending_count_ > 0 && pending_front().trigger_t_us + config_.min_lag_us <= edge_.t_us) {
        open_trigger_ = pending_front();
        open_solicited_ = true;
        pending_pop();
        ++exposures_confirmed_;
      } else {
        open_solicited_ = false;
        ++feedback_unsolicited_;
      }
      open_ = true;
      open_start_t_us_ = edge_.t_us;
      have_edge_ = false;
      continue;
    }

    if (open_) {
      Exposure x = open_record(0);
      x.feedback_end_t_us = edge_.t_us;
      const uint64_t duration_us = edge_.t_us - open_start_t_us_;
      x.duration_us = duration_us > UINT32_MAX ? UINT32_MAX : static_cast<uint32_t>(duration_us);
      out[n++] = x;
      open_ = false;
    } else {
      ++stray_edges_;
    }
    have_edge_ = false;
  }
  return n;
}

}  // namespace icgt::core
