#include "crc16.h"

#if defined(__AVR__)
#include <util/crc16.h>
#endif

uint16_t crc16_update(uint16_t crc, uint8_t byte) {
#if defined(__AVR__)
  // avr-libc's hand-written assembly of exactly the loop below (polynomial 0x1021, MSB first).
  return _crc_xmodem_update(crc, byte);
#else
  crc ^= (uint16_t)((uint16_t)byte << 8);
  for (uint8_t bit = 0; bit < 8; ++bit) {
    crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
  }
  return crc;
#endif
}

uint16_t crc16(const uint8_t *data, size_t len) {
  uint16_t crc = CRC16_INIT;
  for (size_t i = 0; i < len; ++i) {
    crc = crc16_update(crc, data[i]);
  }
  return crc;
}
