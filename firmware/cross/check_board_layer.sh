#!/usr/bin/env bash
# The Teensy board layer cannot be built here (the Teensy core is not installable), so it is
# checked against the fake Teensyduino API in firmware/board/teensy/fake_arduino/:
#  1. host g++ with ASan/UBSan, as Teensy 3.6 and as Teensy 4.1: board layer + main.cpp +
#     the core, linked with the fakes and run (board_host_check.cpp);
#  2. arm-none-eabi-g++ -fsyntax-only for Cortex-M4 and Cortex-M7, where int/long sizes and
#     hence overload resolution are the Teensy's.
# Usage: firmware/cross/check_board_layer.sh   (from anywhere; builds into build/board-check)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
OUT="$ROOT/build/board-check"
mkdir -p "$OUT"

BOARD="$ROOT/firmware/board/teensy"
FAKE="$BOARD/fake_arduino"
INCLUDES=(-I"$FAKE" -I"$BOARD" -I"$ROOT/firmware/lib" -I"$ROOT/firmware/lib/protocol")
WARN=(-Wall -Wextra -Werror -Wshadow -Wnon-virtual-dtor -Wold-style-cast)
FIRMWARE_SOURCES=("$BOARD/teensy_board.cpp" "$ROOT/firmware/src/main.cpp")
CORE_SOURCES=("$ROOT"/firmware/lib/protocol/*.cpp "$ROOT"/firmware/lib/core/*.cpp "$ROOT/firmware/lib/hal/hal.cpp")

for variant in teensy36:__MK66FX1M0__ teensy41:__IMXRT1062__; do
  name="${variant%%:*}"
  macro="${variant#*:}"
  echo "board layer, host run as $name"
  "${CXX:-g++}" -std=c++17 -O1 -g "${WARN[@]}" -fsanitize=address,undefined -fno-sanitize-recover=all \
    -D"$macro" -DICGT_FIRMWARE_VERSION=0.1.0 "${INCLUDES[@]}" \
    "${FIRMWARE_SOURCES[@]}" "$FAKE/fake_arduino.cpp" "$FAKE/board_host_check.cpp" "${CORE_SOURCES[@]}" \
    -o "$OUT/board_host_check_$name"
  "$OUT/board_host_check_$name"
done

if command -v arm-none-eabi-g++ > /dev/null; then
  for variant in "cortex-m4 -mfpu=fpv4-sp-d16 -D__MK66FX1M0__" "cortex-m7 -mfpu=fpv5-d16 -D__IMXRT1062__"; do
    read -r cpu fpu macro <<< "$variant"
    echo "board layer, arm-none-eabi-g++ -fsyntax-only for $cpu ($macro)"
    for src in "${FIRMWARE_SOURCES[@]}"; do
      arm-none-eabi-g++ -std=gnu++17 -mcpu="$cpu" -mthumb "$fpu" -mfloat-abi=hard -Os -fno-exceptions -fno-rtti \
        "${WARN[@]}" "$macro" -DICGT_FIRMWARE_VERSION=0.1.0 "${INCLUDES[@]}" -fsyntax-only "$src"
    done
  done
else
  echo "arm-none-eabi-g++ not found: run .ci/run (apt-get install gcc-arm-none-eabi)" >&2
  exit 1
fi
echo "board layer checks passed"
