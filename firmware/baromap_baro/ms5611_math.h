// TE MS5611 calibration check and compensation (data sheet MS5611-01BA03: first and second
// order temperature compensation; application note AN520: CRC-4 of the PROM). Plain C++ so the
// host tests pin it to the data sheet's example with g++.
#ifndef BAROMAP_MS5611_MATH_H
#define BAROMAP_MS5611_MATH_H

#include <stdint.h>

static const uint8_t MS5611_PROM_WORDS = 8;  // C0 (factory) .. C6, C7 (CRC-4 in bits 3..0)

// True when the PROM's CRC-4 matches and the words are not a dead (all 0) or floating (all 1)
// bus.
bool ms5611_prom_valid(const uint16_t prom[MS5611_PROM_WORDS]);

// CRC-4 of the PROM as AN520 computes it (bits 3..0 of C7 are not included).
uint8_t ms5611_crc4(const uint16_t prom[MS5611_PROM_WORDS]);

// Temperature (0.01 degC) and pressure (Pa * 256, Q24.8) from the raw conversions D1
// (pressure) and D2 (temperature), with the second-order correction below 20 degC.
void ms5611_compensate(const uint16_t prom[MS5611_PROM_WORDS], uint32_t d1, uint32_t d2,
                       int32_t *temperature_centi, uint32_t *pressure_q24_8);

#endif
