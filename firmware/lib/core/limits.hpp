// Every limit the device enforces on START_CAPTURE and CONFIGURE, in one place.
//
// The host mirrors this file in host/icgt/device/limits.py (tests/device/test_limits.py reads
// the constants below and fails when the two disagree), so that a value the device would
// refuse is refused when the recorder's configuration is loaded or a ground station asks,
// never later in flight. A refusal names the limit in ACK.detail (proto::Limit).
//
// The limits are the same on every board that runs this core (Teensy 3.6, Teensy 4.1, the
// simulator, the QEMU build): the trigger runs on a 1 us alarm on each of them.
#pragma once

#include <cstdint>

namespace icgt::core::limits {

// Trigger (START_CAPTURE). 50 ms between shots = 20 fps, the fastest burst of the cameras the
// unit is built for (Sony Alpha 9, electronic shutter); the trigger and pairing queues are
// sized for it (trigger.hpp, exposure_pairing.hpp).
inline constexpr uint32_t kMinIntervalUs = 50'000;
inline constexpr uint32_t kMaxIntervalUs = 3'600'000'000u;
// Remote-release inputs need a press of a few ms to register; 1 s is a long press.
inline constexpr uint32_t kMinPulseUs = 1'000;
inline constexpr uint32_t kMaxPulseUs = 1'000'000;

// Host silence (START_CAPTURE.host_timeout_ms, 0 = never). A live host sends a frame every second at
// least (HOST_RECEIVED, and TIME_SYNC faster): 5 s is five of them missed in a row, never a slow loop.
// 24 h is longer than any battery.
inline constexpr uint32_t kMinHostTimeoutMs = 5'000;
inline constexpr uint32_t kMaxHostTimeoutMs = 86'400'000;

// Exposure pairing (CONFIGURE.feedback_timeout_us, feedback_min_lag_us).
inline constexpr uint32_t kMinFeedbackTimeoutUs = 1'000;
inline constexpr uint32_t kMaxFeedbackTimeoutUs = 2'000'000;
inline constexpr uint32_t kMaxFeedbackMinLagUs = 1'000'000;
// feedback_timeout_us = 0: the timeout is derived at START_CAPTURE as min lag + interval less
// an eighth (the window a feedback edge may arrive in stays shorter than the interval, so a
// missed exposure never shifts the pairing of the next), or min lag + 0.5 s for a single shot,
// at most kMaxFeedbackTimeoutUs.
inline constexpr uint32_t kAutoWindowEighths = 7;
inline constexpr uint32_t kAutoSingleWindowUs = 500'000;

// Sensors (CONFIGURE). BNO055: the fusion output is 100 Hz (Bosch BNO055 datasheet: fusion modes output at 100 Hz).
inline constexpr uint16_t kImuMaxRateHz = 100;
inline constexpr uint8_t kImuFirstFusionMode = 0x08;  // IMUPLUS
inline constexpr uint8_t kImuLastFusionMode = 0x0C;   // NDOF
// LIDAR-Lite: the driver paces acquisitions at most this fast; what the part delivers with a
// preset is LidarLite::max_rate_hz() (Garmin: v3 270 Hz typical at the default preset).
inline constexpr uint16_t kLidarMaxRateHz = 500;
inline constexpr uint8_t kLidarV3Presets = 6;
inline constexpr uint8_t kLidarV3hpPresets = 7;

// The derived feedback timeout for a capture (feedback_timeout_us = 0).
[[nodiscard]] constexpr uint32_t auto_feedback_timeout_us(uint32_t min_lag_us, uint32_t interval_us, bool single) {
  const uint64_t window = single ? uint64_t{kAutoSingleWindowUs} : uint64_t{interval_us} * kAutoWindowEighths / 8;
  const uint64_t t = uint64_t{min_lag_us} + window;
  return t > kMaxFeedbackTimeoutUs ? kMaxFeedbackTimeoutUs : static_cast<uint32_t>(t);
}

}  // namespace icgt::core::limits
