#!/usr/bin/env bash
# Fails (exit 1, naming each file and line) if an Arduino or Teensy core header is included
# anywhere under firmware/ except the board layer (firmware/board/) and the Teensy
# composition root (firmware/src/main.cpp): everything else must build on the host and in
# the simulator.
# Usage: firmware/cross/check_no_arduino.sh [firmware-dir]   (default: this repository's)
#        firmware/cross/check_no_arduino.sh --self-test      (proves the check can fail)
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"

# Headers of the Arduino API, the Teensy cores (teensy3/, teensy4/) and Teensyduino's
# bundled libraries. Case-sensitive and anchored on the closing delimiter, so the codec's own
# "wire.hpp" and the C library's <time.h> do not match.
HEADERS='Arduino|WProgram|wiring|wiring_private|pins_arduino|core_pins|core_id|avr_functions|avr_emulation|
kinetis|imxrt|usb_dev|usb_serial|usb_desc|usb_names|HardwareSerial|Stream|Print|Printable|WString|
IntervalTimer|elapsedMillis|DMAChannel|EventResponder|FlexIO_t4|Wire|WireKinetis|WireIMXRT|i2c_t3|SPI|EEPROM|
TimeLib|Time|DS1307RTC|TeensyThreads|util/atomic|avr/[A-Za-z_]+'
HEADERS="$(tr -d '\n' <<< "$HEADERS")"
PATTERN="^[[:space:]]*#[[:space:]]*include[[:space:]]*[<\"]($HEADERS)\\.h[>\"]"

check() {
  local firmware="$1" hits
  hits="$(grep -rnE --include='*.h' --include='*.hpp' --include='*.c' --include='*.cc' --include='*.cpp' \
          --include='*.ino' "$PATTERN" "$firmware" \
          | grep -vE "^$firmware/board/|^$firmware/src/main\\.cpp:" || true)"
  if [ -n "$hits" ]; then
    echo "Arduino/Teensy headers outside firmware/board/ and firmware/src/main.cpp:" >&2
    echo "$hits" >&2
    return 1
  fi
  echo "no Arduino/Teensy header outside the board layer ($firmware)"
}

if [ "${1:-}" = "--self-test" ]; then
  tmp="$(mktemp -d)"
  trap 'rm -rf "$tmp"' EXIT
  mkdir -p "$tmp/fw/lib/core" "$tmp/fw/board/teensy" "$tmp/fw/src"
  printf '#include <Arduino.h>\n' > "$tmp/fw/board/teensy/ok.cpp"
  printf '#include <Wire.h>\n' > "$tmp/fw/src/main.cpp"
  printf '#include "wire.hpp"\n#include <time.h>\n' > "$tmp/fw/lib/core/fine.cpp"
  check "$tmp/fw" > /dev/null || { echo "self-test: allowed includes were flagged" >&2; exit 1; }
  printf '  #  include "IntervalTimer.h"\n' > "$tmp/fw/lib/core/bad.hpp"
  if check "$tmp/fw" 2> /dev/null; then echo "self-test: a forbidden include was not flagged" >&2; exit 1; fi
  echo "check_no_arduino self-test passed"
  exit 0
fi

check "$(cd "${1:-$HERE/..}" && pwd)"
