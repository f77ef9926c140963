// A stand-in for the few Teensyduino calls and registers the board layer
// (firmware/board/teensy) and the composition root (firmware/src/main.cpp) use, with
// Teensyduino's names and signatures, so both compile, type-check and run on the host (the
// idea of ArduinoJson's extras/tests/Helpers/Arduino.h). Nothing else may include it: the
// real header comes from the Teensy core. Behaviour is in fake_arduino.cpp, steered through
// fake_control.h. Built once as Teensy 3.6 (__MK66FX1M0__) and once as Teensy 4.1
// (__IMXRT1062__): IRQ numbers, priorities, Wire codes and Serial results follow the board.
#pragma once

#include <cstddef>
#include <cstdint>

#define HIGH 1
#define LOW 0
#define INPUT 0
#define OUTPUT 1
#define INPUT_PULLUP 2
#define CHANGE 4
#define NUM_DIGITAL_PINS 64
#define digitalPinToInterrupt(p) ((p) < NUM_DIGITAL_PINS ? (p) : -1)

uint32_t micros();
uint32_t millis();
void pinMode(uint8_t pin, uint8_t mode);
void digitalWriteFast(uint8_t pin, uint8_t val);
uint8_t digitalReadFast(uint8_t pin);
void attachInterrupt(uint8_t pin, void (*function)(void), int mode);
void detachInterrupt(uint8_t pin);
// Macros on the Teensy; functions here, which is the same at every call site.
void noInterrupts();
void interrupts();

// NVIC (both cores: a byte per interrupt at 0xE000E400). A function here, so the fake knows
// which interrupt runs at which priority.
void fake_nvic_set_priority(int irq, uint8_t priority);
#define NVIC_SET_PRIORITY(irqnum, priority) fake_nvic_set_priority((irqnum), (priority))

// DWT cycle counter: a read-only function here (the fake records the priority it is read at).
uint32_t fake_read_cyccnt();
#define ARM_DWT_CYCCNT (fake_read_cyccnt())

#if defined(__IMXRT1062__)
extern volatile uint32_t F_CPU_ACTUAL;
// imxrt.h IRQ numbers.
enum IRQ_NUMBER_t { IRQ_USB1 = 113, IRQ_PIT = 122, IRQ_GPIO6789 = 157 };
// SNVS battery-backed general purpose registers.
extern volatile uint32_t fake_snvs_lpgpr[4];
#define SNVS_LPGPR0 (fake_snvs_lpgpr[0])
#else
#define F_CPU 180000000
// kinetis.h IRQ numbers of the MK66FX1M0.
enum IRQ_NUMBER_t { IRQ_PIT_CH0 = 68, IRQ_USBOTG = 73, IRQ_PORTA = 87, IRQ_PORTE = 91 };
extern volatile uint32_t fake_arm_demcr;
extern volatile uint32_t fake_arm_dwt_ctrl;
#define ARM_DEMCR fake_arm_demcr
#define ARM_DEMCR_TRCENA (1 << 24)
#define ARM_DWT_CTRL fake_arm_dwt_ctrl
#define ARM_DWT_CTRL_CYCCNTENA (1 << 0)
// pins_arduino.h: the pin's PORTx_PCRn address. Fake addresses, never dereferenced.
const volatile uint32_t* fake_port_config_register(uint8_t pin);
#define portConfigRegister(pin) (fake_port_config_register(pin))
// The K66 VBAT register file (the board layer names it through this macro).
extern volatile uint32_t fake_vbat_register_file[8];
#define ICGT_VBAT_REGISTER_FILE (fake_vbat_register_file)
#endif

class usb_serial_class {
 public:
  void begin(long baud);
  int available();
  int read();
  int availableForWrite();
  size_t write(uint8_t b);
  size_t write(const uint8_t* buffer, size_t size);
  void send_now();
  uint8_t dtr();
  operator bool();
};
extern usb_serial_class Serial;

class teensy3_clock_class {
 public:
  static unsigned long get();
  static void set(unsigned long t);
};
extern teensy3_clock_class Teensy3Clock;

void setup();
void loop();
