// Build-time settings of the barometer board firmware (ATmega328P, 16 MHz: Uno, Nano).
#ifndef BAROMAP_CONFIG_H
#define BAROMAP_CONFIG_H

#include <stdint.h>

static const uint8_t FW_MAJOR = 1;
static const uint8_t FW_MINOR = 0;
static const uint8_t FW_PATCH = 0;

static const uint32_t UART_BAUD = 115200;
static const uint32_t I2C_HZ = 400000;

// Defaults after reset (firmware/PROTOCOL.md section 4).
static const uint8_t DEFAULT_RATE_HZ = 25;
static const uint8_t DEFAULT_OSRS_P = 16;
static const uint8_t DEFAULT_OSRS_T = 2;
static const uint8_t DEFAULT_IIR_FILTER = 16;

static const uint32_t STATUS_PERIOD_US = 1000000;    // STATUS frame
static const uint32_t PROBE_RETRY_US = 500000;       // search again for an absent sensor
static const uint32_t MODE_CHECK_PERIOD_US = 1000000;  // re-read the mode register
static const uint32_t I2C_TIMEOUT_US = 5000;         // one transaction, at most 26 bytes
static const uint32_t IDENTIFY_BLINK_US = 2000000;
static const uint8_t LOST_AFTER_FAILURES = 3;        // consecutive failed transactions
static const uint8_t NO_DATA_LIMIT = 10;             // reads of the 0x80000 reset value

#endif
