// Bosch BMP280 calibration words and integer compensation (data sheet BST-BMP280-DS001,
// section 3.11.3: 32-bit temperature formula, 64-bit pressure formula returning Pa in Q24.8).
// Plain C++ so the host tests pin it to the data sheet's worked example with g++.
// Every intermediate is an explicitly sized type: `int` is 16 bits on the AVR.
#ifndef BAROMAP_BMP280_MATH_H
#define BAROMAP_BMP280_MATH_H

#include <stdint.h>

static const uint8_t BMP280_CALIB_LEN = 24;   // registers 0x88..0x9F
static const int32_t BMP280_ADC_SKIPPED = 0x80000;  // data register reset value: no measurement

struct Bmp280Calib {
  uint16_t T1;
  int16_t T2;
  int16_t T3;
  uint16_t P1;
  int16_t P2;
  int16_t P3;
  int16_t P4;
  int16_t P5;
  int16_t P6;
  int16_t P7;
  int16_t P8;
  int16_t P9;
};

// Words from registers 0x88..0x9F (little-endian). False when they cannot be a real sensor's
// (a floating bus reads all ones, a dead one all zeros; P1 = 0 would divide by zero).
bool bmp280_parse_calib(const uint8_t raw[BMP280_CALIB_LEN], Bmp280Calib *out);

// 20-bit ADC value from the three data registers (msb, lsb, xlsb[7:4]).
int32_t bmp280_adc20(const uint8_t *msb_lsb_xlsb);

// Fine temperature carried into the pressure formula.
int32_t bmp280_t_fine(const Bmp280Calib &c, int32_t adc_T);

// Temperature in 0.01 degC.
int32_t bmp280_temperature_centi(int32_t t_fine);

// Pressure in Pa * 256 (Q24.8); 0 if the calibration would divide by zero.
uint32_t bmp280_pressure_q24_8(const Bmp280Calib &c, int32_t t_fine, int32_t adc_P);

#endif
