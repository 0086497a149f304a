// Interrupt-driven, non-blocking I2C (TWI) master for the ATmega328P (AVR only).
// One transaction at a time: write up to TWI_MAX_WRITE bytes, then optionally a repeated start
// and a read. The loop starts it and polls; the ISR moves it along; poll() enforces a timeout
// and recovers the bus, so a missing or stuck sensor can never hang the firmware (the core's
// Wire library blocks while it waits).
#ifndef BAROMAP_TWI_MASTER_H
#define BAROMAP_TWI_MASTER_H

#include <stdint.h>

namespace twi {

static const uint8_t MAX_WRITE = 4;

enum Status : uint8_t {
  IDLE = 0,
  BUSY,
  DONE,
  ERR_ADDR_NACK,  // nobody answered the address
  ERR_DATA_NACK,  // a written byte was refused
  ERR_BUS,        // bus error or lost arbitration
  ERR_TIMEOUT,    // did not finish in time: TWI reset, bus clocked free
};

void begin(uint32_t hz);

// Start a transaction with the 7-bit address `addr`. `read_buf` must stay valid until the
// transaction ends. False if one is already running or the lengths are out of range.
bool start(uint8_t addr, const uint8_t *write_data, uint8_t write_len, uint8_t *read_buf,
           uint8_t read_len, uint32_t now_us, uint32_t timeout_us);

// BUSY while running; the final status exactly once, then IDLE.
Status poll(uint32_t now_us);

// True when a transaction has ended and poll() has not collected it (interrupts off is fine).
bool finished();

// TWSR status code of the last failure (for error frames).
uint8_t last_hw_status();

}  // namespace twi

#endif
