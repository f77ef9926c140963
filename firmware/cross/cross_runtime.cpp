// Minimal bare-metal runtime for the firmware/cross images: vector table, reset (FPU on,
// .data copied, .bss zeroed, stack painted, static constructors run), fault traps, and the
// C++ ABI hooks the core's static objects and polymorphic classes need, written so that
// nothing here ever reaches the heap. Memory layout: mps2.ld.
#include "cross_runtime.hpp"

#include <cstddef>
#include <cstdint>
#include <new>

extern "C" {
extern uint32_t __data_start[];
extern uint32_t __data_end[];
extern const uint32_t __data_load[];
extern uint32_t __bss_start[];
extern uint32_t __bss_end[];
extern uint32_t __stack_top[];
extern uint32_t __stack_limit[];
extern void (*__init_array_start[])();
extern void (*__init_array_end[])();
int main();
}

namespace icgt::cross {
namespace {

constexpr uint32_t kStackPaint = 0xA5A5'5A5Au;

// ARM semihosting: operation in r0, argument in r1, BKPT 0xAB (the M-profile trap).
int semihost(int op, const void* arg) {
  register int r0 __asm__("r0") = op;
  register const void* r1 __asm__("r1") = arg;
  __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
  return r0;
}

constexpr int kSysWrite0 = 0x04;
constexpr int kSysExitExtended = 0x20;
constexpr uint32_t kAdpStoppedApplicationExit = 0x20026;

[[noreturn]] void trap(ExitCode code, const char* why) {
  write(why);
  exit(code);
}

}  // namespace

void write(const char* text) { (void)semihost(kSysWrite0, text); }

void write_u32(uint32_t value) {
  char digits[11];
  int n = 10;
  digits[n] = '\0';
  do {
    digits[--n] = static_cast<char>('0' + value % 10);
    value /= 10;
  } while (value != 0);
  write(&digits[n]);
}

void exit(ExitCode code) {
  // SYS_EXIT_EXTENDED makes QEMU exit with `code` as its own status.
  const uint32_t block[2] = {kAdpStoppedApplicationExit, static_cast<uint32_t>(code)};
  (void)semihost(kSysExitExtended, block);
  for (;;) {
  }
}

std::size_t stack_used_bytes() {
  const uint32_t* p = __stack_limit;
  while (p < __stack_top && *p == kStackPaint) ++p;
  return static_cast<std::size_t>(reinterpret_cast<uintptr_t>(__stack_top) - reinterpret_cast<uintptr_t>(p));
}

}  // namespace icgt::cross

extern "C" {

[[noreturn]] void icgt_cross_start() {
  const uint32_t* src = __data_load;
  for (uint32_t* dst = __data_start; dst < __data_end;) *dst++ = *src++;
  for (uint32_t* dst = __bss_start; dst < __bss_end;) *dst++ = 0;
  // Paint the stack reservation below our own frame, for stack_used_bytes().
  uint32_t* const sp = static_cast<uint32_t*>(__builtin_frame_address(0)) - 16;
  for (uint32_t* p = __stack_limit; p < sp;) *p++ = icgt::cross::kStackPaint;
  for (void (**ctor)() = __init_array_start; ctor < __init_array_end; ++ctor) (*ctor)();
  icgt::cross::exit(main() == 0 ? icgt::cross::ExitCode::ok : icgt::cross::ExitCode::check_failed);
}

// Enables the FPU (CP10/CP11 full access in CPACR) before any compiled code runs: with
// -mfloat-abi=hard the compiler may use FP registers anywhere, and an FP instruction with the
// FPU off is a UsageFault. Hence a naked handler with no prologue.
[[noreturn]] __attribute__((naked)) void Reset_Handler() {
  __asm__ volatile(
      "ldr r0, =0xE000ED88\n"
      "ldr r1, [r0]\n"
      "orr r1, r1, #(0xF << 20)\n"
      "str r1, [r0]\n"
      "dsb\n"
      "isb\n"
      "b icgt_cross_start\n");
}

[[noreturn]] void icgt_cross_fault() { icgt::cross::trap(icgt::cross::ExitCode::fault, "FAULT: CPU exception\n"); }

// Static objects with destructors register them here. A bare-metal image never exits, so
// there is nothing to record; newlib's atexit() (which may allocate) is never linked.
int __aeabi_atexit(void*, void (*)(void*), void*) { return 0; }
void* __dso_handle = nullptr;

void __cxa_pure_virtual() { icgt::cross::trap(icgt::cross::ExitCode::pure_virtual, "FAULT: pure virtual call\n"); }

__attribute__((section(".isr_vector"), used)) void (*const g_vectors[16])() = {
    reinterpret_cast<void (*)()>(__stack_top),  // initial stack pointer
    Reset_Handler,
    icgt_cross_fault,  // NMI
    icgt_cross_fault,  // HardFault
    icgt_cross_fault,  // MemManage
    icgt_cross_fault,  // BusFault
    icgt_cross_fault,  // UsageFault
    nullptr,           // reserved
    nullptr,
    nullptr,
    nullptr,
    icgt_cross_fault,  // SVCall: nothing here issues SVC
    icgt_cross_fault,  // DebugMonitor
    nullptr,           // reserved
    icgt_cross_fault,  // PendSV
    icgt_cross_fault,  // SysTick: never enabled
};

}  // extern "C"

// No operator delete here: the hal's interfaces have protected non-virtual destructors, so no
// HAL class (the probe's stubs, the board layer) has a deleting destructor and nothing
// references operator delete. Should one appear, libstdc++'s version would bring free(),
// which the --wrap in build.sh turns into a link failure naming the caller.
