#include "bmp280_math.h"

namespace {

uint16_t u16le(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }

int16_t s16le(const uint8_t *p) { return (int16_t)u16le(p); }

}  // namespace

bool bmp280_parse_calib(const uint8_t raw[BMP280_CALIB_LEN], Bmp280Calib *out) {
  out->T1 = u16le(raw + 0);
  out->T2 = s16le(raw + 2);
  out->T3 = s16le(raw + 4);
  out->P1 = u16le(raw + 6);
  out->P2 = s16le(raw + 8);
  out->P3 = s16le(raw + 10);
  out->P4 = s16le(raw + 12);
  out->P5 = s16le(raw + 14);
  out->P6 = s16le(raw + 16);
  out->P7 = s16le(raw + 18);
  out->P8 = s16le(raw + 20);
  out->P9 = s16le(raw + 22);
  bool all_ones = true;
  for (uint8_t i = 0; i < BMP280_CALIB_LEN; ++i) {
    all_ones = all_ones && raw[i] == 0xFF;
  }
  return !all_ones && out->T1 != 0 && out->T2 != 0 && out->P1 != 0;
}

int32_t bmp280_adc20(const uint8_t *b) {
  return (int32_t)(((uint32_t)b[0] << 12) | ((uint32_t)b[1] << 4) | ((uint32_t)b[2] >> 4));
}

int32_t bmp280_t_fine(const Bmp280Calib &c, int32_t adc_T) {
  int32_t var1 = (((adc_T >> 3) - (int32_t)c.T1 * 2) * ((int32_t)c.T2)) >> 11;
  int32_t d = (adc_T >> 4) - (int32_t)c.T1;
  int32_t var2 = (((d * d) >> 12) * ((int32_t)c.T3)) >> 14;
  return var1 + var2;
}

int32_t bmp280_temperature_centi(int32_t t_fine) { return (t_fine * 5 + 128) >> 8; }

uint32_t bmp280_pressure_q24_8(const Bmp280Calib &c, int32_t t_fine, int32_t adc_P) {
  // Bosch's formula shifts signed values left; a left shift of a negative number is undefined
  // in C++, so those shifts are written as the multiplications they mean (same code on AVR).
  int64_t var1 = (int64_t)t_fine - 128000;
  int64_t var2 = var1 * var1 * (int64_t)c.P6;
  var2 = var2 + var1 * (int64_t)c.P5 * ((int64_t)1 << 17);
  var2 = var2 + (int64_t)c.P4 * ((int64_t)1 << 35);
  var1 = ((var1 * var1 * (int64_t)c.P3) >> 8) + var1 * (int64_t)c.P2 * ((int64_t)1 << 12);
  var1 = (((int64_t)1 << 47) + var1) * ((int64_t)c.P1) >> 33;
  if (var1 == 0) {
    return 0;
  }
  int64_t p = 1048576 - (int64_t)adc_P;
  p = ((p * ((int64_t)1 << 31) - var2) * 3125) / var1;
  var1 = (((int64_t)c.P9) * (p >> 13) * (p >> 13)) >> 25;
  var2 = (((int64_t)c.P8) * p) >> 19;
  p = ((p + var1 + var2) >> 8) + (int64_t)c.P7 * 16;
  return (uint32_t)p;
}
