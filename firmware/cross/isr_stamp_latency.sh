#!/usr/bin/env bash
# Counts, for each board's CPU, how many instructions the edge interrupt's trampoline (our
# first code in the interrupt, teensy_board.cpp edge_trampoline<0>) executes before it
# reads the DWT cycle counter (ARM_DWT_CYCCNT, 0xE0001004) that stamps the edge. FAILS if
# the read is not among the first 4 instructions (nothing may be moved before the stamp).
# The board layer is compiled as on the Teensy (-O2, as PlatformIO builds Teensy sketches
# by default with "faster") against the fake core, with the counter redefined as the real
# register so the load is the real one. The cycles before our code (exception entry and the
# core's pin-interrupt dispatcher) are in firmware/board/teensy/README.md "ISR latency".
# Usage: firmware/cross/isr_stamp_latency.sh   (builds into build/isr-latency)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
OUT="$ROOT/build/isr-latency"
mkdir -p "$OUT/include"
BOARD="$ROOT/firmware/board/teensy"
# The fake Arduino.h, then the real register definition of the cycle counter (CMSIS/core).
cat > "$OUT/include/Arduino.h" <<HDR
#include "$BOARD/fake_arduino/Arduino.h"
#undef ARM_DWT_CYCCNT
#define ARM_DWT_CYCCNT (*(volatile uint32_t *)0xE0001004)
HDR
status=0
for variant in "teensy41 cortex-m7 -mfpu=fpv5-d16 -D__IMXRT1062__" "teensy36 cortex-m4 -mfpu=fpv4-sp-d16 -D__MK66FX1M0__"; do
  read -r board cpu fpu macro <<< "$variant"
  obj="$OUT/teensy_board_$cpu.o"
  arm-none-eabi-g++ -std=gnu++17 -mcpu="$cpu" -mthumb "$fpu" -mfloat-abi=hard -O2 -fno-exceptions -fno-rtti \
    -fno-threadsafe-statics "$macro" -DICGT_FIRMWARE_VERSION=0.1.0 -I"$OUT/include" -I"$BOARD/fake_arduino" \
    -I"$BOARD" -I"$ROOT/firmware/lib" -I"$ROOT/firmware/lib/protocol" -c "$BOARD/teensy_board.cpp" -o "$obj"
  # The trampoline's instructions, then its literal pool; find the register that gets the
  # DWT base (0xE0001000) and the first load from base + 4.
  result="$(arm-none-eabi-objdump -d -C "$obj" | awk '
    /edge_trampoline<0u>\(\)>:$/ { on = 1; next }
    on && /^$/ { on = 0 }
    on && /^ +[0-9a-f]+:/ && !/\.word/ { print }')"
  # Resolve the literal pool words in the shell (mawk has no regex captures).
  base_reg="" load_index=""
  i=0
  while IFS= read -r l; do
    i=$((i + 1))
    if [[ "$l" =~ ldr(\.w)?[[:space:]]+(r[0-9]+),\ \[pc,\ \#[0-9]+\][[:space:]]+@\ \(([0-9a-f]+) ]]; then
      reg="${BASH_REMATCH[2]}" lit="${BASH_REMATCH[3]}"
      word="$(arm-none-eabi-objdump -d "$obj" | awk -v a="$lit:" '$1 == a && !done { print $2; done = 1 }')"
      [ "$word" = "e0001000" ] && base_reg="$reg"
      [ "$word" = "e0001004" ] && { base_reg="$reg"; load_index="$i"; break; }
    elif [ -n "$base_reg" ] && [[ "$l" =~ ldr(\.w)?[[:space:]]+r[0-9]+,\ \[$base_reg,\ \#4\] ]]; then
      load_index="$i"
      break
    fi
  done <<< "$result"
  if [ -z "$load_index" ]; then
    echo "FAIL: $board ($cpu): no cycle-counter load found in edge_trampoline<0>" >&2
    echo "$result" >&2
    status=1
  elif [ "$load_index" -gt 4 ]; then
    echo "FAIL: $board ($cpu): the cycle counter is read by instruction $load_index of the trampoline (> 4)" >&2
    status=1
  else
    echo "$board ($cpu): edge stamp = instruction $load_index of our interrupt code (cycle counter read)"
  fi
done
exit "$status"
