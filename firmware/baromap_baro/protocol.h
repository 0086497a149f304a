// The board's wire protocol (firmware/PROTOCOL.md): frame layout, encoders for the frames the
// board sends, parser and validator for the commands it receives. Plain C++ without Arduino
// dependencies so the host tests check it against firmware/test_vectors.txt with g++.
// Fields are written one by one, little-endian; no struct is ever copied onto the wire.
#ifndef BAROMAP_PROTOCOL_H
#define BAROMAP_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

namespace proto {

static const uint8_t VERSION = 1;
static const uint8_t VERSION_MINOR = 0;
static const uint8_t HEADER_LEN = 8;
static const uint8_t CRC_LEN = 2;
static const uint8_t MAX_PAYLOAD = 48;
static const uint8_t MIN_FRAME = HEADER_LEN + CRC_LEN;
static const uint8_t MAX_FRAME = HEADER_LEN + MAX_PAYLOAD + CRC_LEN;  // 58
static const uint8_t MAX_ENCODED = MAX_FRAME + 1;                     // 59, without delimiter
static const uint8_t MAX_WIRE = MAX_ENCODED + 1;                      // with the 0x00

enum FrameType : uint8_t {
  HELLO = 0x01,
  SAMPLE = 0x02,
  STATUS = 0x03,
  ERROR = 0x04,
  ACK = 0x05,
  SET_RATE = 0x81,
  SET_OVERSAMPLING = 0x82,
  IDENTIFY = 0x83,
  TEST_HANG = 0xF0,  // only in test builds (-DBAROMAP_TEST_HOOKS): never answered
};

enum SensorModel : uint8_t { SENSOR_NONE = 0, SENSOR_BMP280 = 1, SENSOR_BME280 = 2, SENSOR_MS5611 = 3 };

enum SensorState : uint8_t { STATE_SEARCHING = 0, STATE_CONFIGURING = 1, STATE_RUNNING = 2 };

enum ErrorCode : uint8_t {
  ERR_SENSOR_NOT_FOUND = 1,
  ERR_WRONG_CHIP_ID = 2,
  ERR_SENSOR_LOST = 3,
  ERR_BAD_CALIBRATION = 4,
  ERR_SENSOR_RESET = 5,
  ERR_NO_DATA = 6,
  ERR_BUS_TIMEOUT = 7,
};

enum AckResult : uint8_t { ACK_OK = 0, ACK_BAD_VALUE = 1, ACK_UNKNOWN_COMMAND = 2, ACK_BAD_LENGTH = 3 };

static const uint8_t MIN_RATE_HZ = 1;
static const uint8_t MAX_RATE_HZ = 50;

struct Hello {
  uint8_t protocol_minor;
  uint8_t fw_major;
  uint8_t fw_minor;
  uint8_t fw_patch;
  uint8_t sensor;
  uint8_t chip_id;
  uint8_t i2c_address;
  uint8_t rate_hz;
  uint8_t osrs_p;
  uint8_t osrs_t;
  uint8_t iir_filter;
  uint8_t reset_cause;
};

struct Sample {
  uint32_t pressure_q24_8;
  int16_t temperature_centi_c;
};

struct Status {
  uint32_t frames_sent;
  uint32_t frames_dropped;
  uint32_t i2c_errors;
  uint32_t samples_missed;
  uint32_t rx_bytes;
  uint32_t rx_frames;
  uint32_t rx_crc_errors;
  uint32_t rx_bad_frames;
  uint32_t rx_overflows;
  uint8_t sensor_state;
};

struct Error {
  uint8_t code;
  uint8_t detail;
  uint16_t count;
};

struct Ack {
  uint8_t command;
  uint16_t command_seq;
  uint8_t result;
};

// Complete wire bytes (COBS + trailing 0x00) of one device frame into out[cap].
// Returns the number of bytes, 0 if `cap` is too small (MAX_WIRE always suffices).
size_t encode_hello(uint16_t seq, uint32_t time_us, const Hello &p, uint8_t *out, size_t cap);
size_t encode_sample(uint16_t seq, uint32_t time_us, const Sample &p, uint8_t *out, size_t cap);
size_t encode_status(uint16_t seq, uint32_t time_us, const Status &p, uint8_t *out, size_t cap);
size_t encode_error(uint16_t seq, uint32_t time_us, const Error &p, uint8_t *out, size_t cap);
size_t encode_ack(uint16_t seq, uint32_t time_us, const Ack &p, uint8_t *out, size_t cap);

// A frame as received: header fields and the payload bytes, CRC checked.
struct Frame {
  uint8_t type;
  uint16_t seq;
  uint32_t time_us;
  uint8_t payload_len;
  uint8_t payload[MAX_PAYLOAD];
};

enum ParseResult : uint8_t { PARSE_OK = 0, PARSE_COBS, PARSE_SHORT, PARSE_CRC, PARSE_VERSION };

// Parse one COBS-encoded frame (without its delimiter).
ParseResult parse_frame(const uint8_t *encoded, size_t len, Frame *out);

// A validated host command.
struct Command {
  uint8_t type;
  uint8_t rate_hz;     // SET_RATE
  uint8_t osrs_p;      // SET_OVERSAMPLING
  uint8_t osrs_t;      // SET_OVERSAMPLING
  uint8_t iir_filter;  // SET_OVERSAMPLING
};

// Check a parsed frame as a command. ACK_OK fills `out`; anything else is the ACK to send.
AckResult validate_command(const Frame &frame, Command *out);

bool valid_oversampling(uint8_t value);  // 1, 2, 4, 8, 16
bool valid_iir_filter(uint8_t value);    // 0, 2, 4, 8, 16

}  // namespace proto

#endif
