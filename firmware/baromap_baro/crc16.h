// CRC-16/IBM-3740 (poly 0x1021, init 0xFFFF, not reflected, no final XOR): check value 0x29B1.
// See firmware/PROTOCOL.md section 3. Plain C++: the host tests compile this file with g++.
#ifndef BAROMAP_CRC16_H
#define BAROMAP_CRC16_H

#include <stddef.h>
#include <stdint.h>

static const uint16_t CRC16_INIT = 0xFFFF;

uint16_t crc16_update(uint16_t crc, uint8_t byte);
uint16_t crc16(const uint8_t *data, size_t len);

#endif
