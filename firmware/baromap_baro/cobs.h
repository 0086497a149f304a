// Consistent Overhead Byte Stuffing (Cheshire & Baker): frames contain no 0x00, so 0x00 can
// delimit them and a receiver resynchronises at the next one. Plain C++ for the host tests.
#ifndef BAROMAP_COBS_H
#define BAROMAP_COBS_H

#include <stddef.h>
#include <stdint.h>

// Encoded size never exceeds this for `len` input bytes (one code byte per started 254).
static inline size_t cobs_max_encoded(size_t len) { return len + len / 254 + 1; }

// Encode `len` bytes into `dst` (no delimiter written). Returns the encoded length, or 0 when
// `dst_cap` is too small (nothing useful is in `dst` then).
size_t cobs_encode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap);

// Decode one frame (without its delimiter). Returns false on malformed input (a zero byte, a
// code running past the end) or when the result does not fit `dst_cap`.
bool cobs_decode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap, size_t *out_len);

#endif
