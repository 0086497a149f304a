#include "protocol.h"

#include "cobs.h"
#include "crc16.h"

namespace proto {

namespace {

// Builds header + payload + CRC in a fixed buffer, field by field, little-endian.
class RawFrame {
 public:
  RawFrame(uint8_t type, uint16_t seq, uint32_t time_us) : len_(0) {
    u8(VERSION);
    u8(type);
    u16(seq);
    u32(time_us);
  }
  void u8(uint8_t v) { buf_[len_++] = v; }
  void u16(uint16_t v) {
    u8((uint8_t)(v & 0xFF));
    u8((uint8_t)(v >> 8));
  }
  void i16(int16_t v) { u16((uint16_t)v); }
  void u32(uint32_t v) {
    u16((uint16_t)(v & 0xFFFF));
    u16((uint16_t)(v >> 16));
  }
  // Append the CRC and write COBS + delimiter into out[cap]; 0 if it does not fit.
  size_t finish(uint8_t *out, size_t cap) {
    u16(crc16(buf_, len_));
    if (cap < 1) {
      return 0;
    }
    size_t n = cobs_encode(buf_, len_, out, cap - 1);
    if (n == 0) {
      return 0;
    }
    out[n] = 0x00;
    return n + 1;
  }

 private:
  uint8_t buf_[MAX_FRAME];
  uint8_t len_;
};

uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }

uint32_t get_u32(const uint8_t *p) { return (uint32_t)get_u16(p) | ((uint32_t)get_u16(p + 2) << 16); }

}  // namespace

size_t encode_hello(uint16_t seq, uint32_t time_us, const Hello &p, uint8_t *out, size_t cap) {
  RawFrame f(HELLO, seq, time_us);
  f.u8(p.protocol_minor);
  f.u8(p.fw_major);
  f.u8(p.fw_minor);
  f.u8(p.fw_patch);
  f.u8(p.sensor);
  f.u8(p.chip_id);
  f.u8(p.i2c_address);
  f.u8(p.rate_hz);
  f.u8(p.osrs_p);
  f.u8(p.osrs_t);
  f.u8(p.iir_filter);
  f.u8(p.reset_cause);
  return f.finish(out, cap);
}

size_t encode_sample(uint16_t seq, uint32_t time_us, const Sample &p, uint8_t *out, size_t cap) {
  RawFrame f(SAMPLE, seq, time_us);
  f.u32(p.pressure_q24_8);
  f.i16(p.temperature_centi_c);
  return f.finish(out, cap);
}

size_t encode_status(uint16_t seq, uint32_t time_us, const Status &p, uint8_t *out, size_t cap) {
  RawFrame f(STATUS, seq, time_us);
  f.u32(p.frames_sent);
  f.u32(p.frames_dropped);
  f.u32(p.i2c_errors);
  f.u32(p.samples_missed);
  f.u32(p.rx_bytes);
  f.u32(p.rx_frames);
  f.u32(p.rx_crc_errors);
  f.u32(p.rx_bad_frames);
  f.u32(p.rx_overflows);
  f.u8(p.sensor_state);
  return f.finish(out, cap);
}

size_t encode_error(uint16_t seq, uint32_t time_us, const Error &p, uint8_t *out, size_t cap) {
  RawFrame f(ERROR, seq, time_us);
  f.u8(p.code);
  f.u8(p.detail);
  f.u16(p.count);
  return f.finish(out, cap);
}

size_t encode_ack(uint16_t seq, uint32_t time_us, const Ack &p, uint8_t *out, size_t cap) {
  RawFrame f(ACK, seq, time_us);
  f.u8(p.command);
  f.u16(p.command_seq);
  f.u8(p.result);
  return f.finish(out, cap);
}

ParseResult parse_frame(const uint8_t *encoded, size_t len, Frame *out) {
  uint8_t raw[MAX_FRAME];
  size_t n = 0;
  if (len > MAX_ENCODED || !cobs_decode(encoded, len, raw, sizeof raw, &n)) {
    return PARSE_COBS;
  }
  if (n < MIN_FRAME) {
    return PARSE_SHORT;
  }
  if (crc16(raw, n - CRC_LEN) != get_u16(raw + n - CRC_LEN)) {
    return PARSE_CRC;
  }
  if (raw[0] != VERSION) {
    return PARSE_VERSION;
  }
  out->type = raw[1];
  out->seq = get_u16(raw + 2);
  out->time_us = get_u32(raw + 4);
  out->payload_len = (uint8_t)(n - MIN_FRAME);
  for (uint8_t i = 0; i < out->payload_len; ++i) {
    out->payload[i] = raw[HEADER_LEN + i];
  }
  return PARSE_OK;
}

bool valid_oversampling(uint8_t value) {
  return value == 1 || value == 2 || value == 4 || value == 8 || value == 16;
}

bool valid_iir_filter(uint8_t value) { return value == 0 || (value != 1 && valid_oversampling(value)); }

AckResult validate_command(const Frame &frame, Command *out) {
  out->type = frame.type;
  switch (frame.type) {
    case SET_RATE:
      if (frame.payload_len < 1) {
        return ACK_BAD_LENGTH;
      }
      if (frame.payload[0] < MIN_RATE_HZ || frame.payload[0] > MAX_RATE_HZ) {
        return ACK_BAD_VALUE;
      }
      out->rate_hz = frame.payload[0];
      return ACK_OK;
    case SET_OVERSAMPLING:
      if (frame.payload_len < 3) {
        return ACK_BAD_LENGTH;
      }
      if (!valid_oversampling(frame.payload[0]) || !valid_oversampling(frame.payload[1]) ||
          !valid_iir_filter(frame.payload[2])) {
        return ACK_BAD_VALUE;
      }
      out->osrs_p = frame.payload[0];
      out->osrs_t = frame.payload[1];
      out->iir_filter = frame.payload[2];
      return ACK_OK;
    case IDENTIFY:
      return ACK_OK;
    default:
      return ACK_UNKNOWN_COMMAND;
  }
}

}  // namespace proto
