#!/usr/bin/env bash
# Bare-metal Cortex-M builds of the firmware core, as CI runs them (Debian's arm-none-eabi-g++
# with newlib-nano). For each CPU:
#   - compiles firmware/lib/{protocol,core}/*.cpp, firmware/lib/hal/hal.cpp and the size
#     probe (size_probe_main.cpp + cross_runtime.cpp) with the firmware's flags;
#   - links against mps2.ld and prints flash = text + data and static RAM = data + bss
#     (the stack is not counted: it is a reservation at the top of RAM, see mps2.ld), split
#     into core (protocol + core + hal), probe (stubs + runtime) and C/C++ library;
#   - FAILS if flash > 64 KiB or static RAM > 32 KiB plus the RESEND history (whole image, probe
#     included), or if the whole static RAM exceeds what the board leaves for it (Teensy 3.6:
#     200 KiB of its 256 KiB, the rest for Teensyduino's USB buffers and the stack; Teensy 4.1:
#     448 KiB of the 512 KiB data-TCM RAM1, the rest is the code's ITCM banks and the stack).
#     The history's rings are sized per board (firmware/lib/core/history.hpp): cortex-m4 builds
#     the Teensy 3.6's, cortex-m7 the Teensy 4.1's; the figures are printed in bytes and minutes
#     of 5 fps exposures (with PPS: 6 events per second);
#   - FAILS if the image could allocate: malloc & co. are wrapped to symbols that do not
#     exist (-Wl,--wrap), so any call fails the link naming its caller; then nm must find no
#     allocator, no operator new and no operator delete in the image (the hal's destructors
#     are protected and non-virtual, so no deleting destructor references one).
#     Wrapping rather than a trapping malloc: a trap only fires on the path a test happens to
#     run, the link fails for every caller, including calls made only after start-up. Since
#     nothing may allocate at all, "after start-up" needs no separate treatment;
#   - runs the image under QEMU (mps2-an386 for the M4, mps2-an500 for the M7) with
#     semihosting if qemu-system-arm is installed: the image exits 0 only if the core booted
#     and answered over its link (see size_probe_main.cpp).
# Usage: firmware/cross/build.sh [cortex-m4] [cortex-m7]   (default: both)
# Output: build/cross/<cpu>/ (objects, size_probe.elf, size_probe.map).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
CROSS="$ROOT/firmware/cross"

FLASH_BUDGET=$((64 * 1024))
RAM_BUDGET=$((32 * 1024))
QEMU_TIMEOUT_S=30

CXX=arm-none-eabi-g++
for tool in "$CXX" arm-none-eabi-size arm-none-eabi-nm; do
  command -v "$tool" > /dev/null || {
    echo "$tool not found: run .ci/run (it installs gcc-arm-none-eabi and newlib)" >&2
    exit 1
  }
done

# -fno-threadsafe-statics as Teensyduino builds: single core, and guard functions would
# drag in libstdc++'s locking.
CXXFLAGS=(-std=c++17 -Os -fno-exceptions -fno-rtti -fno-threadsafe-statics -ffunction-sections -fdata-sections
  -Wall -Wextra -Werror -I"$ROOT/firmware/lib" -I"$ROOT/firmware/lib/protocol")
# Every allocator entry point newlib has (the _r forms are what newlib calls internally).
HEAP_FUNCS=(malloc calloc realloc free memalign aligned_alloc _malloc_r _calloc_r _realloc_r _free_r _memalign_r)
WRAPS=()
for f in "${HEAP_FUNCS[@]}"; do WRAPS+=("-Wl,--wrap=$f"); done
HEAP_SYMBOLS_RE="^(__wrap_)?($(IFS='|'; echo "${HEAP_FUNCS[*]}")|_sbrk|_sbrk_r)\$|^_Zn[wa]|^_Zd[la]"

build_one() {
  local cpu="$1" fpu machine
  local board board_ram_budget
  case "$cpu" in
    cortex-m4) fpu=fpv4-sp-d16 machine=mps2-an386 board=TEENSY36 board_ram_budget=$((200 * 1024)) ;;  # MK66FX1M0
    cortex-m7) fpu=fpv5-d16 machine=mps2-an500 board=TEENSY41 board_ram_budget=$((448 * 1024)) ;;     # i.MX RT1062
    *) echo "unknown CPU $cpu (cortex-m4 or cortex-m7)" >&2; return 1 ;;
  esac
  local arch=(-mcpu="$cpu" -mthumb -mfpu="$fpu" -mfloat-abi=hard -DICGT_BOARD_$board)
  local out="$ROOT/build/cross/$cpu"
  rm -rf "$out"
  mkdir -p "$out/core" "$out/probe"

  echo "== $cpu ($fpu, hard float): compiling"
  local pids=() objs=() src obj group
  for src in "$ROOT"/firmware/lib/protocol/*.cpp "$ROOT"/firmware/lib/core/*.cpp "$ROOT"/firmware/lib/hal/hal.cpp \
             "$CROSS/size_probe_main.cpp" "$CROSS/cross_runtime.cpp"; do
    case "$src" in "$CROSS"/*) group=probe ;; *) group=core ;; esac
    obj="$out/$group/$(basename "$(dirname "$src")")_$(basename "${src%.cpp}").o"
    objs+=("$obj")
    "$CXX" "${arch[@]}" "${CXXFLAGS[@]}" -c "$src" -o "$obj" &
    pids+=($!)
  done
  local pid failed=0
  for pid in "${pids[@]}"; do wait "$pid" || failed=1; done
  [ "$failed" -eq 0 ] || { echo "FAIL: $cpu: compilation failed (see above)" >&2; return 1; }

  local elf="$out/size_probe.elf" map="$out/size_probe.map"
  if ! "$CXX" "${arch[@]}" -nostartfiles --specs=nano.specs --specs=nosys.specs -Wl,--gc-sections \
      -T "$CROSS/mps2.ld" -Wl,-Map="$map" "${WRAPS[@]}" "${objs[@]}" -o "$elf"; then
    echo "FAIL: $cpu: link failed. An undefined __wrap_malloc/__wrap_free/... above means the code it names" >&2
    echo "      allocates from the heap, which the firmware must never do." >&2
    return 1
  fi

  # --- heap check -----------------------------------------------------------------------
  local found bad=""
  found="$(arm-none-eabi-nm "$elf" | awk '{print $NF}' | grep -E "$HEAP_SYMBOLS_RE" | sort -u || true)"
  for sym in $found; do bad+=" $sym"; done
  if [ -n "$bad" ]; then
    echo "FAIL: $cpu: the image contains heap functions:$bad" >&2
    echo "      (callers: arm-none-eabi-nm -u build/cross/$cpu/core/*.o | grep -E '$HEAP_SYMBOLS_RE')" >&2
    return 1
  fi
  # The core's own objects must not even reference one (the trap above is for the stubs).
  local core_refs
  core_refs="$(arm-none-eabi-nm -u -A "$out"/core/*.o | awk '{print $1, $NF}' \
               | while read -r file sym; do grep -qE "$HEAP_SYMBOLS_RE" <<< "$sym" && echo "$file $sym"; done || true)"
  if [ -n "$core_refs" ]; then
    echo "FAIL: $cpu: core objects reference heap functions:" >&2
    echo "$core_refs" >&2
    return 1
  fi
  echo "heap check: core references no heap function; image has no allocator, no operator new, no operator delete"

  # --- size and budgets -------------------------------------------------------------------
  "$CXX" "${arch[@]}" "${CXXFLAGS[@]}" -c "$CROSS/history_size.cpp" -o "$out/history_size.o"
  local history_bytes event_slots
  read_u32() {
    arm-none-eabi-objcopy -O binary --only-section=".rodata.$1" "$out/history_size.o" "$out/$1.bin"
    od -An -tu4 "$out/$1.bin" | tr -d ' '
  }
  history_bytes="$(read_u32 icgt_history_bytes)"
  event_slots="$(read_u32 icgt_history_event_slots)"
  awk -v cpu="$cpu" -v b="$board" -v h="$history_bytes" -v e="$event_slots" 'BEGIN {
    printf "%s (%s): RESEND history %d B (%.1f KiB), %d event slots = %.1f min of 5 fps exposures with PPS\n",
           cpu, b, h, h / 1024, e, e / 6 / 60 }'
  arm-none-eabi-size "$elf"
  local text data bss flash ram
  read -r text data bss _ < <(arm-none-eabi-size "$elf" | awk 'NR == 2 {print $1, $2, $3}')
  flash=$((text + data))
  ram=$((data + bss))
  # Where the flash comes from: input sections of the link map, grouped by object directory
  # (input sizes: merged strings make the three add up to a little more than the total).
  awk -v core="$out/core/" -v probe="$out/probe/" '
    function hex(s,   i, v) {  # mawk has no strtonum
      v = 0
      s = tolower(substr(s, 3))
      for (i = 1; i <= length(s); ++i) v = v * 16 + index("0123456789abcdef", substr(s, i, 1)) - 1
      return v
    }
    function add(sec, size, file,   g) {
      g = "C/C++ library"
      if (index(file, core) == 1) g = "core (protocol, core, hal)"
      if (index(file, probe) == 1) g = "probe (stubs, runtime)"
      if (sec ~ /^\.(text|rodata|ARM|init_array|preinit_array|data)/) f[g] += size
    }
    /^Linker script and memory map/ { on = 1; next }
    !on { next }
    /^ [.A-Za-z_][^ ]*$/ { pending = $1; next }
    pending != "" && /^ +0x[0-9a-f]+ +0x[0-9a-f]+ / { add(pending, hex($2), $3); pending = ""; next }
    /^ [.A-Za-z_][^ ]* +0x[0-9a-f]+ +0x[0-9a-f]+ / { add($1, hex($3), $4); pending = ""; next }
    { pending = "" }
    END { for (g in f) printf "  flash from %-27s %6d B\n", g, f[g] }' "$map" | sort
  # Where the static RAM goes: the App object is the core's whole state; the rest is the probe.
  arm-none-eabi-nm -S --size-sort -C "$elf" | awk '$3 ~ /^[dDbB]$/ && $1 >= "20000000" {
      n = $2; v = 0
      for (i = 1; i <= length(n); ++i) v = v * 16 + index("0123456789abcdef", tolower(substr(n, i, 1))) - 1
      name = $4; for (i = 5; i <= NF; ++i) name = name " " $i
      line[++k] = sprintf("  RAM %-34s %6d B", name, v) }
    END { for (i = k; i > k - 4 && i > 0; --i) print line[i] }'
  awk -v cpu="$cpu" -v f="$flash" -v r="$ram" -v fb="$FLASH_BUDGET" -v rb="$RAM_BUDGET" -v h="$history_bytes" \
      -v bb="$board_ram_budget" 'BEGIN {
    printf "%s: flash %d B (%.1f KiB of %d KiB), static RAM %d B (%.1f KiB of %d KiB + the history, %d KiB for the board), stack not included\n",
           cpu, f, f / 1024, fb / 1024, r, r / 1024, rb / 1024, bb / 1024 }'
  local over=0
  if [ "$flash" -gt "$FLASH_BUDGET" ]; then echo "FAIL: $cpu: flash $flash B > budget $FLASH_BUDGET B" >&2; over=1; fi
  if [ "$ram" -gt $((RAM_BUDGET + history_bytes)) ]; then
    echo "FAIL: $cpu: static RAM $ram B > budget $RAM_BUDGET B + history $history_bytes B" >&2; over=1
  fi
  if [ "$ram" -gt "$board_ram_budget" ]; then
    echo "FAIL: $cpu: static RAM $ram B > what the $board leaves for it ($board_ram_budget B)" >&2; over=1
  fi
  [ "$over" -eq 0 ] || return 1

  # --- boot under QEMU --------------------------------------------------------------------
  if ! command -v qemu-system-arm > /dev/null; then
    echo "FAIL: $cpu: qemu-system-arm not installed; the boot check cannot run (.ci/run installs it)" >&2
    return 1
  fi
  echo "== $cpu: booting under qemu-system-arm -M $machine"
  local qemu_status=0
  timeout --kill-after=5 "$QEMU_TIMEOUT_S" qemu-system-arm -M "$machine" -display none -monitor none -serial none \
    -semihosting-config enable=on,target=native -kernel "$elf" < /dev/null || qemu_status=$?
  case "$qemu_status" in
    0) echo "$cpu: QEMU boot check passed" ;;
    124 | 137) echo "FAIL: $cpu: QEMU did not exit within ${QEMU_TIMEOUT_S} s (killed)" >&2; return 1 ;;
    *) echo "FAIL: $cpu: QEMU exited with status $qemu_status (see cross_runtime.hpp ExitCode)" >&2; return 1 ;;
  esac
}

cpus=("$@")
[ "${#cpus[@]}" -gt 0 ] || cpus=(cortex-m4 cortex-m7)
status=0
for cpu in "${cpus[@]}"; do build_one "$cpu" || status=1; done
exit "$status"
