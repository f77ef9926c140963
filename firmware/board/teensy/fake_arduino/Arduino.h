// A stand-in for the few Teensyduino calls the board layer (firmware/board/teensy) and the
// composition root (firmware/src/main.cpp) use, with Teensyduino's signatures, so both
// compile, type-check and run on the host (the idea of ArduinoJson's
// extras/tests/Helpers/Arduino.h). Nothing else may include it: the real header comes from
// the Teensy core. Behaviour is in fake_arduino.cpp, steered through fake_control.h.
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

#if defined(__IMXRT1062__)
extern volatile uint32_t F_CPU_ACTUAL;
extern volatile uint32_t fake_arm_dwt_cyccnt;
#define ARM_DWT_CYCCNT fake_arm_dwt_cyccnt
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
