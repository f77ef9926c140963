// The hardware interface of the ICGT firmware core.
//
// Everything the portable core needs from a board, reduced to a few byte- and edge-level
// primitives (the ArduPilot AP_HAL habit). Drivers and logic receive these through their
// constructors; only composition roots (firmware/src/main.cpp for the Teensy, the
// simulator's main, test fixtures) build concrete ones. No Arduino header may appear here
// or anywhere under firmware/lib.
//
// Contracts that hold for every implementation:
//  - No call blocks for longer than one I2C transfer (bounded by the bus timeout).
//  - Callbacks registered with EdgeInput and Alarm run in interrupt context on the device:
//    they may only touch lock-free single-producer/single-consumer state.
//  - All times are microseconds of the one 64-bit device clock (Clock::now_us).
//  - Board objects are static (or owned by value); none is ever deleted through an interface
//    pointer. The interfaces' destructors are therefore protected and non-virtual: a virtual
//    one makes the compiler emit a deleting destructor per class, which references
//    operator delete and links the allocator into a board that must have none (the Teensy
//    build pulled in malloc/free that way). firmware/cross/check_board_layer.sh checks it.
#pragma once

#include <cstddef>
#include <cstdint>

namespace icgt::hal {

// The device clock: microseconds since boot, 64 bits, monotonic, never wraps.
class Clock {
 public:
  [[nodiscard]] virtual uint64_t now_us() const = 0;

 protected:
  // Non-virtual and protected: nothing deletes a board object through the interface, so no
  // deleting destructor (and no operator delete) is ever emitted for one. See the header comment.
  ~Clock() = default;
};

enum class I2cStatus : uint8_t {
  ok = 0,
  nack_address,  // nobody answered the address byte (part absent, resetting or unplugged); also
                 // any NACK on a board that cannot tell address from data (Teensy 4)
  nack_data,     // the part refused a data byte (only boards that can tell, e.g. Teensy 3)
  timeout,       // bus stuck (SDA/SCL held low), clock stretched past the limit, or the
                 // transfer exceeded the bus timeout
  bus_error,     // arbitration lost, controller FIFO error, other bus fault
};

// How a write followed by a read in one transfer is joined on the bus.
enum class I2cJoin : uint8_t {
  repeated_start,  // S addr+W reg Sr addr+R data P   (BusIO write_then_read, LIDAR-Lite v3HP)
  stop,            // S addr+W reg P S addr+R data P   (LIDAR-Lite v3 guidelines)
};

// One I2C bus. A single primitive, as in ArduPilot's AP_HAL::Device::transfer().
class I2cBus {
 public:
  // Writes send_len bytes to addr7 (send_len == 0 is an address-only probe), then, if
  // recv_len > 0, reads recv_len bytes (joined as `join` says). A read-only transfer has
  // send_len == 0 and recv_len > 0. recv is only meaningful on I2cStatus::ok.
  [[nodiscard]] virtual I2cStatus transfer(uint8_t addr7, const uint8_t* send, std::size_t send_len,
                                           uint8_t* recv, std::size_t recv_len,
                                           I2cJoin join = I2cJoin::repeated_start) = 0;

 protected:
  ~I2cBus() = default;  // as Clock's
};

// Register helpers on top of I2cBus, bound to one device address (non-virtual).
class I2cDevice {
 public:
  I2cDevice(I2cBus& bus, uint8_t addr7, I2cJoin join = I2cJoin::repeated_start)
      : bus_(bus), addr7_(addr7), join_(join) {}

  [[nodiscard]] uint8_t address() const { return addr7_; }
  [[nodiscard]] I2cBus& bus() const { return bus_; }

  // Address-only write; ok means the part acknowledged its address.
  [[nodiscard]] I2cStatus probe() { return bus_.transfer(addr7_, nullptr, 0, nullptr, 0, join_); }

  [[nodiscard]] I2cStatus write_register(uint8_t reg, uint8_t value) {
    const uint8_t buf[2] = {reg, value};
    return bus_.transfer(addr7_, buf, 2, nullptr, 0, join_);
  }

  [[nodiscard]] I2cStatus read_registers(uint8_t reg, uint8_t* out, std::size_t n) {
    return bus_.transfer(addr7_, &reg, 1, out, n, join_);
  }

  [[nodiscard]] I2cStatus read_register(uint8_t reg, uint8_t& out) { return read_registers(reg, &out, 1); }

 private:
  I2cBus& bus_;
  uint8_t addr7_;
  I2cJoin join_;
};

// A push-pull output line (shutter, focus). Called from interrupt context by the trigger.
class DigitalOut {
 public:
  virtual void write(bool high) = 0;

 protected:
  ~DigitalOut() = default;  // as Clock's
};

// An input line with an edge interrupt (camera feedback, GPS PPS). The board takes the
// timestamp in the interrupt, as close to the edge as it can, and hands it to the handler.
class EdgeInput {
 public:
  using Handler = void (*)(void* ctx, bool level_high, uint64_t t_us);
  // Calls handler on every edge (both directions) until detach(). Returns false if the
  // line cannot deliver interrupts (not wired on this board).
  [[nodiscard]] virtual bool attach(Handler handler, void* ctx) = 0;
  virtual void detach() = 0;
  [[nodiscard]] virtual bool read() const = 0;

 protected:
  ~EdgeInput() = default;  // as Clock's
};

// A one-shot hardware timer interrupt at an absolute device time (IntervalTimer on the
// Teensy). The handler runs in interrupt context with the time it actually fired.
class Alarm {
 public:
  using Handler = void (*)(void* ctx, uint64_t now_us);
  virtual void set_handler(Handler handler, void* ctx) = 0;
  // Fires once at t_us (at once if t_us is in the past). Re-arming replaces the pending time.
  virtual void arm_at(uint64_t t_us) = 0;
  virtual void cancel() = 0;

 protected:
  ~Alarm() = default;  // as Clock's
};

// The link to the host (USB CDC serial on the Teensy, a pty or socket in the simulator).
// Never blocks: write() takes what fits and returns how much.
class ByteStream {
 public:
  [[nodiscard]] virtual std::size_t write(const uint8_t* data, std::size_t len) = 0;
  // Bytes write() would accept now without blocking.
  [[nodiscard]] virtual std::size_t writable() const = 0;
  [[nodiscard]] virtual std::size_t read(uint8_t* out, std::size_t cap) = 0;
  // False while no host has the port open (USB unplugged, pty closed).
  [[nodiscard]] virtual bool connected() const = 0;

 protected:
  ~ByteStream() = default;  // as Clock's
};

// Battery-backed real-time clock, whole UTC seconds since the Unix epoch.
class Rtc {
 public:
  // False if the RTC has never been set (or lost power): its time means nothing.
  [[nodiscard]] virtual bool get_utc_s(int64_t& utc_s) const = 0;
  [[nodiscard]] virtual bool set_utc_s(int64_t utc_s) = 0;

 protected:
  ~Rtc() = default;  // as Clock's
};

}  // namespace icgt::hal
