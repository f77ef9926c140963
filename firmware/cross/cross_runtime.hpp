// The few services the bare-metal cross images (size_probe_main.cpp) need from their
// runtime (cross_runtime.cpp): text out and exit status through semihosting (QEMU with
// -semihosting-config enable=on), and the stack high-water mark.
// QEMU-only: on hardware without a debugger the semihosting BKPT would fault.
#pragma once

#include <cstddef>
#include <cstdint>

namespace icgt::cross {

// Exit statuses of the cross images, distinct so a QEMU run says what went wrong.
enum class ExitCode : int {
  ok = 0,
  check_failed = 1,  // the image ran but its own checks failed
  fault = 3,         // HardFault / MemManage / BusFault / UsageFault / NMI
  heap_used = 4,     // no longer raised: nothing can reach operator delete (cross_runtime.cpp)
  pure_virtual = 5,  // a pure virtual function was called
};

void write(const char* text);
void write_u32(uint32_t value);
[[noreturn]] void exit(ExitCode code);
// Bytes of the stack reservation ever used since reset (the reset handler paints it).
[[nodiscard]] std::size_t stack_used_bytes();

}  // namespace icgt::cross
