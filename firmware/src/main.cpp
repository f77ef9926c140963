// The Teensy composition root: the board's HAL objects and the application, all in static
// storage (no heap), wired together here and nowhere else. setup() brings the board up and
// starts the application; loop() runs one application step.
#include <Arduino.h>
#include <Wire.h>

#include "core/app.hpp"
#include "pins.h"
#include "teensy_board.h"

// platformio.ini passes the version as bare tokens (-D ICGT_FIRMWARE_VERSION=0.1.0): a quoted
// string would need shell-specific escaping on every host that builds the firmware.
#ifndef ICGT_FIRMWARE_VERSION
#error "ICGT_FIRMWARE_VERSION is not set; build with PlatformIO (platformio.ini sets it)"
#endif
#define ICGT_STRINGIFY_TOKENS(x) #x
#define ICGT_STRINGIFY(x) ICGT_STRINGIFY_TOKENS(x)

namespace {

namespace board = icgt::board::teensy;
namespace pins = icgt::board::teensy::pins;

#if defined(__IMXRT1062__)
constexpr icgt::proto::Board kBoard = icgt::proto::Board::teensy41;
#elif defined(__MK66FX1M0__)
constexpr icgt::proto::Board kBoard = icgt::proto::Board::teensy36;
#else
#error "ICGT runs on Teensy 3.6 (__MK66FX1M0__) and Teensy 4.1 (__IMXRT1062__)"
#endif

// Teensyduino documents no call that returns the board's serial number (the core builds the
// USB serial-number string from chip fuses internally). HELLO therefore says 0, and the host
// identifies the unit by the USB serial number its operating system reports for the port.
constexpr uint32_t kSerialNumber = 0;

// Declaration order is construction order: every object is built before the App that uses it.
board::TeensyClock g_clock;
board::TeensyUsbSerial g_link;
board::TeensyI2cBus g_i2c(Wire);
board::TeensyAlarm g_trigger_alarm(g_clock);
board::TeensyDigitalOut g_shutter(pins::kShutter);
board::TeensyDigitalOut g_focus(pins::kFocus);
board::TeensyEdgeInput g_feedback(pins::kFeedback, pins::kFeedbackPull, g_clock);
board::TeensyEdgeInput g_pps(pins::kPps, pins::kPpsPull, g_clock);
board::TeensyRtc g_rtc;

const icgt::core::AppPorts kPorts{g_clock,   g_link,       g_i2c,     g_trigger_alarm, g_shutter,
                                  g_focus,   &g_feedback,  &g_pps,    g_rtc};
const icgt::core::BoardIdentity kIdentity{kBoard, kSerialNumber, ICGT_STRINGIFY(ICGT_FIRMWARE_VERSION)};

icgt::core::App g_app(kPorts, kIdentity);

}  // namespace

void setup() {
  // USB Serial needs no begin(): Teensyduino brings USB up before setup() runs.
  g_clock.begin();
  g_shutter.begin();
  g_focus.begin();
  g_feedback.begin();
  g_pps.begin();
  g_trigger_alarm.begin();
  g_i2c.begin();
  g_app.begin();
}

void loop() { g_app.poll(); }
