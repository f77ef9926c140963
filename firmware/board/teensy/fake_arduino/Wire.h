// Fake of Teensyduino's Wire.h: the TwoWire members the board layer calls, with the Teensy
// overload set (so an ambiguous call fails here as it would on the Teensy). See Arduino.h.
#pragma once

#include <cstddef>
#include <cstdint>

class TwoWire {
 public:
  void begin();
  void setClock(uint32_t frequency);
  void beginTransmission(uint8_t address);
  void beginTransmission(int address);
  uint8_t endTransmission(uint8_t sendStop);
  uint8_t endTransmission();
  uint8_t requestFrom(uint8_t address, uint8_t quantity, uint8_t sendStop);
  uint8_t requestFrom(uint8_t address, uint8_t quantity);
  uint8_t requestFrom(int address, int quantity, int sendStop);
  uint8_t requestFrom(int address, int quantity);
  size_t write(uint8_t data);
  size_t write(const uint8_t* data, size_t quantity);
  int available();
  int read();
};
extern TwoWire Wire;
