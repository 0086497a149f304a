// Interrupt-driven UART0 with fixed ring buffers (AVR only). Replaces the Arduino core's
// Serial so the firmware can count receive overruns and overflows, and so a frame is queued
// whole or not at all: the loop never waits for the line.
#ifndef BAROMAP_SERIAL_PORT_H
#define BAROMAP_SERIAL_PORT_H

#include <stdint.h>

namespace serial_port {

void begin(uint32_t baud);

// Next received byte, or -1 when none is waiting.
int16_t read();

// True when received bytes are waiting (safe to call with interrupts off).
bool rx_pending();

// Receive overruns (UART data overrun or ring buffer full) since the last call.
uint8_t take_overflows();

// Queue `len` bytes for transmission, all or nothing. False when they do not fit.
bool write(const uint8_t *data, uint8_t len);

}  // namespace serial_port

#endif
