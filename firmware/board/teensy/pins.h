// Every pin the ICGT firmware uses on the Teensy, in one place. README.md ("Flashing the
// board and wiring") shows the same table for the person with the soldering iron.
//
// Teensy 3.6 and Teensy 4.1 share these pin numbers, so one table serves both boards.
// Both run at 3.3 V and neither tolerates 5 V on any of these pins.
//
//  | signal   | pin | direction | electrical                                                  |
//  |----------|-----|-----------|-------------------------------------------------------------|
//  | focus    |  2  | output    | push-pull 3.3 V; drive the camera's half-press line through |
//  |          |     |           | an optocoupler or open-collector transistor                 |
//  | shutter  |  3  | output    | as focus, for the full-press (release) line                 |
//  | feedback |  4  | input     | internal pull-up; hot shoe / flash sync pulls it to ground  |
//  | PPS      |  5  | input     | no pull; GPS 1PPS output (3.3 V logic)                      |
//  | SDA      | 18  | I2C       | Wire (SDA0), 400 kHz; external 2.2-4.7 kOhm pull-up to 3.3 V  |
//  | SCL      | 19  | I2C       | Wire (SCL0)                                                 |
//
// The I2C pins are Wire's defaults on both boards, so the code never names them; they are
// listed here (and asserted nowhere) only so this file stays the one place to look.
//
// Pure constants: no Arduino header, so the table can be read and checked on the host.
#pragma once

#include <cstdint>

namespace icgt::board::teensy::pins {

enum class InputPull : uint8_t { none, up };

inline constexpr uint8_t kFocus = 2;
inline constexpr uint8_t kShutter = 3;
inline constexpr uint8_t kFeedback = 4;
inline constexpr uint8_t kPps = 5;
inline constexpr uint8_t kSda = 18;  // Wire default; documentation only
inline constexpr uint8_t kScl = 19;  // Wire default; documentation only

// A hot shoe or flash-sync cord is a contact to ground: without a pull-up the line floats.
inline constexpr InputPull kFeedbackPull = InputPull::up;
// A GPS drives PPS push-pull; a pull-up would only fight a receiver that is powered down.
inline constexpr InputPull kPpsPull = InputPull::none;

inline constexpr uint32_t kI2cClockHz = 400'000;  // BNO055 and LIDAR-Lite both allow fast mode

}  // namespace icgt::board::teensy::pins
