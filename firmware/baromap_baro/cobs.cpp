#include "cobs.h"

size_t cobs_encode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap) {
  if (dst_cap == 0) {
    return 0;
  }
  size_t code_at = 0;  // where the current block's code byte goes
  size_t out = 1;
  uint8_t code = 1;
  for (size_t i = 0; i < len; ++i) {
    if (src[i] != 0) {
      if (out >= dst_cap) {
        return 0;
      }
      dst[out++] = src[i];
      ++code;
    }
    if (src[i] == 0 || code == 0xFF) {
      dst[code_at] = code;
      code = 1;
      code_at = out;
      // A full block at the very end of the data implies no zero: no new block follows.
      if (src[i] == 0 || i + 1 < len) {
        if (out >= dst_cap) {
          return 0;
        }
        ++out;
      }
    }
  }
  if (code_at < out) {
    dst[code_at] = code;
  }
  return out;
}

bool cobs_decode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap, size_t *out_len) {
  size_t i = 0;
  size_t out = 0;
  while (i < len) {
    uint8_t code = src[i];
    if (code == 0 || i + code > len) {
      return false;
    }
    for (size_t k = i + 1; k < i + code; ++k) {
      if (src[k] == 0 || out >= dst_cap) {
        return false;
      }
      dst[out++] = src[k];
    }
    i += code;
    if (code != 0xFF && i < len) {
      if (out >= dst_cap) {
        return false;
      }
      dst[out++] = 0;
    }
  }
  *out_len = out;
  return true;
}
