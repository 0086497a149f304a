#include "ms5611_math.h"

uint8_t ms5611_crc4(const uint16_t prom[MS5611_PROM_WORDS]) {
  uint16_t rem = 0;
  for (uint8_t i = 0; i < 2 * MS5611_PROM_WORDS; ++i) {
    uint16_t word = prom[i >> 1];
    if (i == 2 * MS5611_PROM_WORDS - 1 || i == 2 * MS5611_PROM_WORDS - 2) {
      word &= 0xFF00;  // the CRC's own nibble (and the rest of C7's low byte) reads as zero
    }
    rem ^= (i & 1) ? (uint16_t)(word & 0x00FF) : (uint16_t)(word >> 8);
    for (uint8_t bit = 0; bit < 8; ++bit) {
      rem = (rem & 0x8000) ? (uint16_t)((rem << 1) ^ 0x3000) : (uint16_t)(rem << 1);
    }
  }
  return (uint8_t)((rem >> 12) & 0x0F);
}

bool ms5611_prom_valid(const uint16_t prom[MS5611_PROM_WORDS]) {
  bool all_zero = true;
  bool all_ones = true;
  for (uint8_t i = 0; i < MS5611_PROM_WORDS; ++i) {
    all_zero = all_zero && prom[i] == 0x0000;
    all_ones = all_ones && prom[i] == 0xFFFF;
  }
  return !all_zero && !all_ones && ms5611_crc4(prom) == (prom[7] & 0x0F);
}

void ms5611_compensate(const uint16_t prom[MS5611_PROM_WORDS], uint32_t d1, uint32_t d2,
                       int32_t *temperature_centi, uint32_t *pressure_q24_8) {
  int32_t dt = (int32_t)d2 - (int32_t)((uint32_t)prom[5] << 8);
  int32_t temp = 2000 + (int32_t)(((int64_t)dt * prom[6]) / 8388608);  // 2^23
  int64_t off = (int64_t)prom[2] * 65536 + ((int64_t)prom[4] * dt) / 128;
  int64_t sens = (int64_t)prom[1] * 32768 + ((int64_t)prom[3] * dt) / 256;
  if (temp < 2000) {
    int64_t t2 = ((int64_t)dt * dt) / 2147483648LL;  // 2^31
    int64_t cold = (int64_t)(temp - 2000) * (temp - 2000);
    int64_t off2 = 5 * cold / 2;
    int64_t sens2 = 5 * cold / 4;
    if (temp < -1500) {
      int64_t very_cold = (int64_t)(temp + 1500) * (temp + 1500);
      off2 += 7 * very_cold;
      sens2 += 11 * very_cold / 2;
    }
    temp -= (int32_t)t2;
    off -= off2;
    sens -= sens2;
  }
  *temperature_centi = temp;
  // The data sheet divides by 2^15 for Pa; dividing by 2^7 keeps 8 more bits: Pa * 256.
  *pressure_q24_8 = (uint32_t)(((int64_t)d1 * sens / 2097152 - off) / 128);  // 2^21, 2^7
}
