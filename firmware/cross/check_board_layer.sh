#!/usr/bin/env bash
# The Teensy board layer cannot be built here (the Teensy core is not installable), so it is
# checked against the fake Teensyduino API in firmware/board/teensy/fake_arduino/:
#  1. host g++ with ASan/UBSan, as Teensy 3.6 and as Teensy 4.1: board layer + main.cpp +
#     the core, linked with the fakes and run (board_host_check.cpp);
#  2. arm-none-eabi-g++ for Cortex-M4 and Cortex-M7 (int/long sizes and hence overload
#     resolution are the Teensy's), objects checked with nm: no reference to malloc/free,
#     operator new or operator delete (the hal's destructors are protected and non-virtual
#     so that no deleting destructor exists; the real Teensy build links the core's malloc
#     otherwise).
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
  # Every allocator entry point newlib has, operator new/delete (all forms) and _sbrk.
  HEAP_RE='^(malloc|calloc|realloc|free|memalign|aligned_alloc|_malloc_r|_calloc_r|_realloc_r|_free_r|_memalign_r|_sbrk|_sbrk_r)$|^_Zn[wa]|^_Zd[la]'
  for variant in "cortex-m4 -mfpu=fpv4-sp-d16 -D__MK66FX1M0__" "cortex-m7 -mfpu=fpv5-d16 -D__IMXRT1062__"; do
    read -r cpu fpu macro <<< "$variant"
    echo "board layer, arm-none-eabi-g++ for $cpu ($macro): compile, then no allocator reference"
    mkdir -p "$OUT/$cpu"
    for src in "${FIRMWARE_SOURCES[@]}"; do
      obj="$OUT/$cpu/$(basename "${src%.cpp}").o"
      # Teensyduino's flags that matter here: no exceptions, no RTTI, no thread-safe statics.
      arm-none-eabi-g++ -std=gnu++17 -mcpu="$cpu" -mthumb "$fpu" -mfloat-abi=hard -Os -fno-exceptions -fno-rtti \
        -fno-threadsafe-statics "${WARN[@]}" "$macro" -DICGT_FIRMWARE_VERSION=0.1.0 "${INCLUDES[@]}" -c "$src" -o "$obj"
      # The real build links the Teensy core, which has malloc; a reference from our objects
      # (a deleting destructor's operator delete, a new) would pull it in. None may exist.
      refs="$(arm-none-eabi-nm -u "$obj" | awk '{print $NF}' | grep -E "$HEAP_RE" || true)"
      if [ -n "$refs" ]; then
        echo "FAIL: $cpu: $(basename "$src") references heap functions:" $refs >&2
        echo "      (a virtual destructor in a hal interface or board class emits a deleting destructor)" >&2
        exit 1
      fi
    done
  done
else
  echo "arm-none-eabi-g++ not found: run .ci/run (apt-get install gcc-arm-none-eabi)" >&2
  exit 1
fi
echo "board layer checks passed"
