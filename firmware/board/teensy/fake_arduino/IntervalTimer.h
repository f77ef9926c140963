// Fake of Teensyduino's IntervalTimer.h: begin() with the Teensy 3 overload set, end(),
// priority(). A started timer fires every period as fake::advance_us() moves time on.
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
  int id_;
};
