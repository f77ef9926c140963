// Interrupt priorities of the ICGT firmware on the Teensy, in one place. Pure constants (no
// Arduino header), so the table is checked on the host and by the fake Teensyduino API.
//
// ARM NVIC priorities: a lower number is more urgent. Both chips implement the top 4 bits
// (16 levels, steps of 16). What the Teensyduino cores set at start-up (cores 1.58/1.59,
// teensy3/mk20dx128.c, teensy4/startup.c, teensy3/usb_dev.c):
//
//  | source                          | Teensy 3.6            | Teensy 4.1                         |
//  |---------------------------------|-----------------------|------------------------------------|
//  | every NVIC interrupt by default | 128                   | 128                                |
//  | SysTick (millis/micros tick)    | 32                    | 32                                 |
//  | USB                             | 112 (IRQ_USBOTG)      | 128 (IRQ_USB1, the default)        |
//  | pin-change interrupts           | 128, one IRQ per port | 128, one IRQ for all (IRQ_GPIO6789)|
//  | IntervalTimer                   | one IRQ per PIT channel, priority() sets it | one IRQ for all four channels (IRQ_PIT): begin()/priority() set it to the most urgent of the *running* channels, end() recomputes it with the ended channel at 255 |
//
// ICGT's choices (this file): the trigger alarm first, then the two edge inputs (camera
// feedback, GPS PPS), both above USB, all below SysTick (whose handler is a few cycles and
// keeps micros() right). The shot is never held up by USB traffic, the edge stamps are never
// delayed by a USB transfer's interrupt, and an edge interrupt can be delayed by the alarm's
// at most (a few microseconds: the shutter write and the trigger's bookkeeping).
//
// Teensy 4: IntervalTimer::end() drops IRQ_PIT to 255 when no other channel runs, and the
// running handler then executes at 255 (an active interrupt runs at its current NVIC
// priority). TeensyAlarm therefore calls the shot handler before it ends the timer, never
// after (teensy_board.cpp, TeensyAlarm::on_interrupt), and the fake core checks the priority
// the shutter line was written at.
#pragma once

#include <cstdint>

namespace icgt::board::teensy::irq {

inline constexpr uint8_t kSysTick = 32;  // the core's; not changed
inline constexpr uint8_t kTriggerAlarm = 48;
inline constexpr uint8_t kEdgeInputs = 64;  // feedback and PPS
inline constexpr uint8_t kCoreDefault = 128;
#if defined(__IMXRT1062__)
inline constexpr uint8_t kUsb = 128;
#else
inline constexpr uint8_t kUsb = 112;
#endif

static_assert(kSysTick < kTriggerAlarm && kTriggerAlarm < kEdgeInputs && kEdgeInputs < kUsb,
              "SysTick > alarm > edges > USB in urgency");
static_assert(kTriggerAlarm % 16 == 0 && kEdgeInputs % 16 == 0, "4 priority bits: multiples of 16");

}  // namespace icgt::board::teensy::irq
