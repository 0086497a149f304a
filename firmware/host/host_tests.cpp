// Host unit tests of the firmware's plain C++ (COBS, CRC, protocol, receive framer, BMP280 and
// MS5611 compensation), compiled with g++ and run by the Python suite. The expected values come from
// firmware/test_vectors.txt, the file the Python codec's tests read too.
//
// usage: host_tests [PATH/TO/test_vectors.txt]

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "bmp280_math.h"
#include "cobs.h"
#include "crc16.h"
#include "ms5611_math.h"
#include "protocol.h"
#include "rx_framer.h"

namespace {

int g_checks = 0;
int g_failures = 0;

void check(bool ok, const std::string &what) {
  ++g_checks;
  if (!ok) {
    ++g_failures;
    std::fprintf(stderr, "FAIL: %s\n", what.c_str());
  }
}

using Bytes = std::vector<uint8_t>;

struct Vector {
  std::string kind;
  std::string name;
  std::map<std::string, std::string> fields;

  bool has(const std::string &key) const { return fields.count(key) != 0; }
  long long num(const std::string &key) const {
    auto it = fields.find(key);
    if (it == fields.end()) {
      std::fprintf(stderr, "vector %s: missing field %s\n", name.c_str(), key.c_str());
      std::exit(2);
    }
    return std::strtoll(it->second.c_str(), nullptr, 10);
  }
  unsigned long hexnum(const std::string &key) const {
    return std::strtoul(fields.at(key).c_str(), nullptr, 16);
  }
  Bytes bytes(const std::string &key) const {
    const std::string &hex = fields.at(key);
    Bytes out;
    for (size_t i = 0; i + 1 < hex.size(); i += 2) {
      out.push_back((uint8_t)std::strtoul(hex.substr(i, 2).c_str(), nullptr, 16));
    }
    return out;
  }
  std::string id() const { return kind + " " + name; }
};

std::vector<Vector> load(const std::string &path) {
  std::ifstream in(path);
  if (!in) {
    std::fprintf(stderr, "cannot open %s\n", path.c_str());
    std::exit(2);
  }
  std::vector<Vector> out;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') {
      continue;
    }
    std::istringstream words(line);
    Vector v;
    words >> v.kind;
    std::string word;
    while (words >> word) {
      size_t eq = word.find('=');
      if (eq == std::string::npos) {
        std::fprintf(stderr, "bad token '%s' in: %s\n", word.c_str(), line.c_str());
        std::exit(2);
      }
      v.fields[word.substr(0, eq)] = word.substr(eq + 1);
    }
    v.name = v.fields["name"];
    out.push_back(v);
  }
  return out;
}

std::string hex(const uint8_t *p, size_t n) {
  std::string s;
  char buf[3];
  for (size_t i = 0; i < n; ++i) {
    std::snprintf(buf, sizeof buf, "%02x", p[i]);
    s += buf;
  }
  return s;
}

uint16_t le16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
uint32_t le32(const uint8_t *p) { return (uint32_t)le16(p) | ((uint32_t)le16(p + 2) << 16); }

void test_crc(const Vector &v) {
  Bytes data = v.bytes("data");
  check(crc16(data.data(), data.size()) == v.hexnum("crc"), v.id());
}

void test_cobs(const Vector &v) {
  Bytes data = v.bytes("data");
  Bytes expected = v.bytes("encoded");
  uint8_t enc[600];
  size_t n = cobs_encode(data.data(), data.size(), enc, sizeof enc);
  check(n == expected.size() && hex(enc, n) == hex(expected.data(), expected.size()),
        v.id() + " encode: got " + hex(enc, n));
  check(n <= cobs_max_encoded(data.size()), v.id() + " within cobs_max_encoded");
  uint8_t dec[600];
  size_t m = 0;
  bool ok = cobs_decode(expected.data(), expected.size(), dec, sizeof dec, &m);
  check(ok && m == data.size() && hex(dec, m) == hex(data.data(), data.size()), v.id() + " decode");
  if (!expected.empty()) {
    // One byte short of room must fail cleanly, never write past the buffer.
    check(cobs_encode(data.data(), data.size(), enc, expected.size() - 1) == 0, v.id() + " cap");
  }
}

size_t encode_device_frame(const Vector &v, uint8_t *out, size_t cap, bool *known) {
  *known = true;
  uint16_t seq = (uint16_t)v.num("seq");
  uint32_t t = (uint32_t)v.num("time_us");
  const std::string &type = v.fields.at("type");
  if (type == "HELLO") {
    proto::Hello p = {(uint8_t)v.num("protocol_minor"), (uint8_t)v.num("fw_major"), (uint8_t)v.num("fw_minor"),
                      (uint8_t)v.num("fw_patch"),       (uint8_t)v.num("sensor"),   (uint8_t)v.num("chip_id"),
                      (uint8_t)v.num("i2c_address"),    (uint8_t)v.num("rate_hz"),  (uint8_t)v.num("osrs_p"),
                      (uint8_t)v.num("osrs_t"),         (uint8_t)v.num("iir_filter"), (uint8_t)v.num("reset_cause")};
    return proto::encode_hello(seq, t, p, out, cap);
  }
  if (type == "SAMPLE") {
    proto::Sample p = {(uint32_t)v.num("pressure_q24_8"), (int16_t)v.num("temperature_centi_c")};
    return proto::encode_sample(seq, t, p, out, cap);
  }
  if (type == "STATUS") {
    proto::Status p = {(uint32_t)v.num("frames_sent"),   (uint32_t)v.num("frames_dropped"),
                       (uint32_t)v.num("i2c_errors"),    (uint32_t)v.num("samples_missed"),
                       (uint32_t)v.num("rx_bytes"),      (uint32_t)v.num("rx_frames"),
                       (uint32_t)v.num("rx_crc_errors"), (uint32_t)v.num("rx_bad_frames"),
                       (uint32_t)v.num("rx_overflows"),  (uint8_t)v.num("sensor_state")};
    return proto::encode_status(seq, t, p, out, cap);
  }
  if (type == "ERROR") {
    proto::Error p = {(uint8_t)v.num("code"), (uint8_t)v.num("detail"), (uint16_t)v.num("count")};
    return proto::encode_error(seq, t, p, out, cap);
  }
  if (type == "ACK") {
    proto::Ack p = {(uint8_t)v.num("command"), (uint16_t)v.num("command_seq"), (uint8_t)v.num("result")};
    return proto::encode_ack(seq, t, p, out, cap);
  }
  *known = false;
  return 0;
}

// Payload fields in wire order with their sizes (negative = signed), per frame type.
const std::map<std::string, std::vector<std::pair<std::string, int>>> &layouts() {
  static const std::map<std::string, std::vector<std::pair<std::string, int>>> table = {
      {"HELLO",
       {{"protocol_minor", 1}, {"fw_major", 1}, {"fw_minor", 1}, {"fw_patch", 1}, {"sensor", 1},
        {"chip_id", 1}, {"i2c_address", 1}, {"rate_hz", 1}, {"osrs_p", 1}, {"osrs_t", 1},
        {"iir_filter", 1}, {"reset_cause", 1}}},
      {"SAMPLE", {{"pressure_q24_8", 4}, {"temperature_centi_c", -2}}},
      {"STATUS",
       {{"frames_sent", 4}, {"frames_dropped", 4}, {"i2c_errors", 4}, {"samples_missed", 4},
        {"rx_bytes", 4}, {"rx_frames", 4}, {"rx_crc_errors", 4}, {"rx_bad_frames", 4},
        {"rx_overflows", 4}, {"sensor_state", 1}}},
      {"ERROR", {{"code", 1}, {"detail", 1}, {"count", 2}}},
      {"ACK", {{"command", 1}, {"command_seq", 2}, {"result", 1}}},
      {"SET_RATE", {{"rate_hz", 1}}},
      {"SET_OVERSAMPLING", {{"osrs_p", 1}, {"osrs_t", 1}, {"iir_filter", 1}}},
      {"IDENTIFY", {}},
  };
  return table;
}

const std::map<std::string, uint8_t> &type_codes() {
  static const std::map<std::string, uint8_t> table = {
      {"HELLO", proto::HELLO},       {"SAMPLE", proto::SAMPLE},
      {"STATUS", proto::STATUS},     {"ERROR", proto::ERROR},
      {"ACK", proto::ACK},           {"SET_RATE", proto::SET_RATE},
      {"SET_OVERSAMPLING", proto::SET_OVERSAMPLING}, {"IDENTIFY", proto::IDENTIFY},
  };
  return table;
}

proto::AckResult ack_code(const std::string &name) {
  if (name == "OK") return proto::ACK_OK;
  if (name == "BAD_VALUE") return proto::ACK_BAD_VALUE;
  if (name == "UNKNOWN_COMMAND") return proto::ACK_UNKNOWN_COMMAND;
  if (name == "BAD_LENGTH") return proto::ACK_BAD_LENGTH;
  std::fprintf(stderr, "unknown ack name %s\n", name.c_str());
  std::exit(2);
}

void test_frame(const Vector &v) {
  Bytes wire = v.bytes("wire");
  check(!wire.empty() && wire.back() == 0x00, v.id() + " ends with the delimiter");
  bool decode_only = v.has("decode_only") && v.num("decode_only") != 0;
  uint8_t out[proto::MAX_WIRE];
  bool known = false;
  size_t n = encode_device_frame(v, out, sizeof out, &known);
  if (known && !decode_only) {
    check(n == wire.size() && hex(out, n) == hex(wire.data(), wire.size()),
          v.id() + " encode: got " + hex(out, n));
    check(encode_device_frame(v, out, wire.size() - 1, &known) == 0, v.id() + " encode cap");
  }
  // Every frame, whatever its direction, parses back to its header and payload fields.
  proto::Frame f;
  proto::ParseResult r = proto::parse_frame(wire.data(), wire.size() - 1, &f);
  check(r == proto::PARSE_OK, v.id() + " parse");
  if (r != proto::PARSE_OK) {
    return;
  }
  const std::string &type = v.fields.at("type");
  check(f.type == type_codes().at(type), v.id() + " type");
  check(f.seq == (uint16_t)v.num("seq"), v.id() + " seq");
  check(f.time_us == (uint32_t)v.num("time_us"), v.id() + " time_us");
  size_t at = 0;
  for (const auto &field : layouts().at(type)) {
    int size = field.second < 0 ? -field.second : field.second;
    if (at + size > f.payload_len) {
      check(false, v.id() + " payload too short for " + field.first);
      return;
    }
    long long got = 0;
    if (size == 1) got = f.payload[at];
    if (size == 2) got = le16(f.payload + at);
    if (size == 4) got = le32(f.payload + at);
    if (field.second == -2) got = (int16_t)got;
    check(got == v.num(field.first), v.id() + " field " + field.first);
    at += size;
  }
  if (v.has("ack")) {
    proto::Command cmd;
    check(proto::validate_command(f, &cmd) == ack_code(v.fields.at("ack")), v.id() + " validate");
    if (type == "SET_RATE" && v.fields.at("ack") == "OK") {
      check(cmd.rate_hz == v.num("rate_hz"), v.id() + " command rate");
    }
  }
}

void test_bad(const Vector &v) {
  Bytes wire = v.bytes("wire");
  const std::string &reason = v.fields.at("reason");
  proto::Frame f;
  proto::ParseResult r = proto::parse_frame(wire.data(), wire.size() - 1, &f);
  if (reason == "cobs") check(r == proto::PARSE_COBS, v.id());
  else if (reason == "short") check(r == proto::PARSE_SHORT, v.id());
  else if (reason == "crc") check(r == proto::PARSE_CRC, v.id());
  else if (reason == "version") check(r == proto::PARSE_VERSION, v.id());
  else if (reason == "type" || reason == "length") {
    // CRC and version are good: the firmware answers such frames with an ACK saying why.
    check(r == proto::PARSE_OK, v.id() + " parses");
    if (r == proto::PARSE_OK && (f.type & 0x80) != 0) {
      proto::Command cmd;
      proto::AckResult a = proto::validate_command(f, &cmd);
      check(a == (reason == "type" ? proto::ACK_UNKNOWN_COMMAND : proto::ACK_BAD_LENGTH),
            v.id() + " ack");
    }
  } else {
    check(false, v.id() + " unknown reason " + reason);
  }
}

void test_bmp280(const Vector &v) {
  Bmp280Calib c = {(uint16_t)v.num("T1"), (int16_t)v.num("T2"), (int16_t)v.num("T3"),
                   (uint16_t)v.num("P1"), (int16_t)v.num("P2"), (int16_t)v.num("P3"),
                   (int16_t)v.num("P4"),  (int16_t)v.num("P5"), (int16_t)v.num("P6"),
                   (int16_t)v.num("P7"),  (int16_t)v.num("P8"), (int16_t)v.num("P9")};
  int32_t t_fine = bmp280_t_fine(c, (int32_t)v.num("adc_T"));
  check(t_fine == v.num("t_fine"), v.id() + " t_fine = " + std::to_string(t_fine));
  check(bmp280_temperature_centi(t_fine) == v.num("T"), v.id() + " T");
  uint32_t p = bmp280_pressure_q24_8(c, t_fine, (int32_t)v.num("adc_P"));
  check(p == (uint32_t)v.num("P"), v.id() + " P = " + std::to_string(p));
}

void test_bmp280_calib(const Vector &v) {
  Bytes raw = v.bytes("raw");
  check(raw.size() == BMP280_CALIB_LEN, v.id() + " raw length");
  Bmp280Calib c;
  bool valid = bmp280_parse_calib(raw.data(), &c);
  check(valid == (v.num("valid") != 0), v.id() + " validity");
  if (valid) {
    check(c.T1 == v.num("T1") && c.T2 == v.num("T2") && c.T3 == v.num("T3"), v.id() + " T words");
    check(c.P1 == v.num("P1") && c.P2 == v.num("P2") && c.P3 == v.num("P3") && c.P4 == v.num("P4") &&
              c.P5 == v.num("P5") && c.P6 == v.num("P6") && c.P7 == v.num("P7") &&
              c.P8 == v.num("P8") && c.P9 == v.num("P9"),
          v.id() + " P words");
  }
}

void test_ms5611(const Vector &v) {
  uint16_t prom[MS5611_PROM_WORDS] = {0,
                                      (uint16_t)v.num("C1"),
                                      (uint16_t)v.num("C2"),
                                      (uint16_t)v.num("C3"),
                                      (uint16_t)v.num("C4"),
                                      (uint16_t)v.num("C5"),
                                      (uint16_t)v.num("C6"),
                                      0};
  int32_t temp = 0;
  uint32_t p = 0;
  ms5611_compensate(prom, (uint32_t)v.num("D1"), (uint32_t)v.num("D2"), &temp, &p);
  check(temp == v.num("TEMP"), v.id() + " TEMP = " + std::to_string(temp));
  check(p == (uint32_t)v.num("P"), v.id() + " P = " + std::to_string(p));
}

void test_ms5611_prom(const Vector &v) {
  Bytes raw = v.bytes("prom");
  check(raw.size() == 2 * MS5611_PROM_WORDS, v.id() + " length");
  uint16_t prom[MS5611_PROM_WORDS];
  for (uint8_t i = 0; i < MS5611_PROM_WORDS; ++i) {
    prom[i] = (uint16_t)((raw[2 * i] << 8) | raw[2 * i + 1]);  // the sensor sends MSB first
  }
  check(ms5611_prom_valid(prom) == (v.num("valid") != 0), v.id() + " validity");
}

// The datasheet's fixed example, independent of the vector file: it must never drift.
void test_datasheet_example() {
  Bmp280Calib c = {27504, 26435, -1000, 36477, -10685, 3024, 2855, 140, -7, 15500, -14600, 6000};
  int32_t t_fine = bmp280_t_fine(c, 519888);
  check(t_fine == 128422, "datasheet t_fine 128422");
  check(bmp280_temperature_centi(t_fine) == 2508, "datasheet T 25.08 degC");
  uint32_t p = bmp280_pressure_q24_8(c, t_fine, 415148);
  // 100653.25 Pa; the data sheet's double-precision formula gives 100653.27 Pa.
  check(p == 25767233u, "datasheet P q24.8");
  double pa = p / 256.0;
  check(pa > 100653.2 && pa < 100653.3, "datasheet P within 0.05 Pa of 100653.27");
  uint8_t regs[3] = {0x65, 0x5A, 0xC0};  // 415148 = 0x655AC
  check(bmp280_adc20(regs) == 415148, "adc20 assembles msb/lsb/xlsb");
  // MS5611 data sheet: 20.07 degC, 1000.09 mbar.
  uint16_t prom[MS5611_PROM_WORDS] = {0, 40127, 36924, 23317, 23282, 33464, 28312, 0};
  int32_t temp = 0;
  uint32_t q = 0;
  ms5611_compensate(prom, 9085466, 8569150, &temp, &q);
  check(temp == 2007, "MS5611 datasheet TEMP 20.07 degC");
  check(q >> 8 == 100009, "MS5611 datasheet P 100009 Pa");
  // AN520's PROM example carries CRC-4 0xB.
  uint16_t an520[MS5611_PROM_WORDS] = {0x3132, 0x3334, 0x3536, 0x3738, 0x3940, 0x4142, 0x4344, 0x450B};
  check(ms5611_crc4(an520) == 0x0B, "AN520 CRC-4 example");
}

// The receive framer: every frame of a stream comes out whole, whatever garbage sits between
// them; over-long runs are reported once and skipped to the next delimiter.
void test_rx_framer(const std::vector<Vector> &vectors) {
  std::vector<Bytes> frames;
  for (const auto &v : vectors) {
    if (v.kind == "frame") frames.push_back(v.bytes("wire"));
  }
  RxFramer framer;
  uint32_t state = 12345;
  auto rnd = [&state]() {
    state = state * 1103515245u + 12345u;
    return (uint8_t)(state >> 16);
  };
  size_t got = 0, oversized = 0, expected_oversized = 0;
  for (size_t round = 0; round < 200; ++round) {
    const Bytes &frame = frames[round % frames.size()];
    // Garbage: random length, random bytes, ending with a 0x00 so it is delimited.
    size_t garbage = rnd() % 3 == 0 ? (size_t)rnd() : (size_t)(rnd() % 8);
    size_t run = 0;
    for (size_t i = 0; i < garbage; ++i) {
      uint8_t b = rnd() | 1;
      ++run;
      if (run == proto::MAX_ENCODED + 1) ++expected_oversized;
      if (framer.push(b) == RxFramer::OVERSIZED) ++oversized;
    }
    framer.push(0x00);
    bool whole = true;
    for (size_t i = 0; i < frame.size(); ++i) {
      RxFramer::Event e = framer.push(frame[i]);
      if (i + 1 < frame.size()) {
        whole = whole && e == RxFramer::NONE;
      } else if (e == RxFramer::FRAME) {
        whole = whole && (size_t)framer.length() + 1 == frame.size() &&
                hex(framer.data(), framer.length()) == hex(frame.data(), frame.size() - 1);
        ++got;
      }
    }
    check(whole, "rx_framer frame " + std::to_string(round) + " intact");
  }
  check(got == 200, "rx_framer delivered every frame");
  check(oversized == expected_oversized && expected_oversized > 0,
        "rx_framer counted each oversized run once (" + std::to_string(oversized) + ")");
}

void test_cobs_random() {
  uint32_t state = 99;
  auto rnd = [&state]() {
    state = state * 1664525u + 1013904223u;
    return (uint8_t)(state >> 24);
  };
  bool ok = true;
  for (int round = 0; round < 2000 && ok; ++round) {
    size_t len = rnd() + (rnd() & 1 ? rnd() : 0);
    Bytes data(len);
    for (auto &b : data) b = (rnd() & 3) == 0 ? 0 : rnd();
    uint8_t enc[1100], dec[1100];
    size_t n = cobs_encode(data.data(), len, enc, sizeof enc);
    size_t m = 0;
    ok = n > 0 && n <= cobs_max_encoded(len);
    for (size_t i = 0; ok && i < n; ++i) ok = enc[i] != 0;
    ok = ok && cobs_decode(enc, n, dec, sizeof dec, &m) && m == len &&
         hex(dec, m) == hex(data.data(), len);
  }
  check(ok, "cobs random round trips");
}

}  // namespace

int main(int argc, char **argv) {
  std::string path = argc > 1 ? argv[1] : "test_vectors.txt";
  std::vector<Vector> vectors = load(path);
  std::map<std::string, int> counts;
  for (const auto &v : vectors) {
    ++counts[v.kind];
    if (v.kind == "crc") test_crc(v);
    else if (v.kind == "cobs") test_cobs(v);
    else if (v.kind == "frame") test_frame(v);
    else if (v.kind == "bad") test_bad(v);
    else if (v.kind == "bmp280") test_bmp280(v);
    else if (v.kind == "bmp280_calib") test_bmp280_calib(v);
    else if (v.kind == "ms5611") test_ms5611(v);
    else if (v.kind == "ms5611_prom") test_ms5611_prom(v);
    else check(false, "unknown vector kind " + v.kind);
  }
  test_datasheet_example();
  test_rx_framer(vectors);
  test_cobs_random();
  std::printf("vectors:");
  for (const auto &kv : counts) std::printf(" %s=%d", kv.first.c_str(), kv.second);
  std::printf("\nhost tests: %d checks, %d failed\n", g_checks, g_failures);
  return g_failures == 0 ? 0 : 1;
}
