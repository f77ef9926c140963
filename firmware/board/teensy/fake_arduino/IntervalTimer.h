// Fake of Teensyduino's IntervalTimer.h: begin() with the Teensy 3 overload set, end(),
// priority(), and each core's priority rules (fake_arduino.cpp): Teensy 3 one NVIC interrupt
// per PIT channel; Teensy 4 one shared IRQ_PIT whose priority begin()/priority()/end() set
// to the most urgent of the running channels (255 for an ended one). begin() takes the first
// free channel, as both cores do. A started timer fires every period as fake::advance_us()
// moves time on, inside its interrupt.
#pragma once

#include <cstdint>

class IntervalTimer {
 public:
  IntervalTimer();
  ~IntervalTimer();
  IntervalTimer(const IntervalTimer&) = delete;
  IntervalTimer& operator=(const IntervalTimer&) = delete;

  bool begin(void (*funct)(), unsigned int microseconds);
  bool begin(void (*funct)(), int microseconds);
  bool begin(void (*funct)(), unsigned long microseconds);
  bool begin(void (*funct)(), long microseconds);
  bool begin(void (*funct)(), float microseconds);
  bool begin(void (*funct)(), double microseconds);
  void end();
  void priority(uint8_t n);

 private:
  bool start(void (*funct)(), uint64_t period_us);
  int channel_ = -1;
  uint8_t nvic_priority_ = 128;
};
