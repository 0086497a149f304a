// The barometer on I2C, as a non-blocking state machine (AVR only): find a BMP280/BME280 at
// 0x76 or 0x77, check its chip id, soft-reset it, read its calibration, configure normal mode,
// then read its data registers when asked. Every step is one I2C transaction started in one
// loop pass and collected in a later one; failures are counted, reported as events and retried,
// never waited out.
#ifndef BAROMAP_BARO_SENSOR_H
#define BAROMAP_BARO_SENSOR_H

#include <stdint.h>

#include "bmp280_math.h"

struct SensorSettings {
  uint8_t osrs_p;      // 1, 2, 4, 8, 16
  uint8_t osrs_t;      // 1, 2, 4, 8, 16
  uint8_t iir_filter;  // 0, 2, 4, 8, 16
};

struct SensorEvent {
  enum Kind : uint8_t { NONE = 0, CONFIGURED, ERROR, SAMPLE, SAMPLE_FAILED };
  Kind kind;
  uint8_t code;    // ERROR: proto::ErrorCode
  uint8_t detail;  // ERROR
  uint16_t count;  // ERROR: consecutive occurrences
  uint32_t pressure_q24_8;       // SAMPLE
  int16_t temperature_centi_c;  // SAMPLE
};

class BaroSensor {
 public:
  void begin(const SensorSettings &settings, uint32_t now_us);

  // New oversampling/filter: applied as soon as the sensor is idle (sleep, config, normal).
  void reconfigure(const SensorSettings &settings);

  // Advance the state machine; at most one event per call.
  void poll(uint32_t now_us, SensorEvent *event);

  // Start reading one sample; false when the sensor is not running or the bus is busy.
  bool start_sample(uint32_t now_us);

  bool running() const;
  bool sampling() const { return state_ == SAMPLE; }
  uint8_t protocol_state() const;  // proto::SensorState
  uint8_t model() const { return model_; }
  uint8_t chip_id() const { return chip_id_; }
  uint8_t address() const { return model_ ? address_ : 0; }
  uint32_t i2c_errors() const { return i2c_errors_; }

 private:
  enum State : uint8_t {
    WAIT_PROBE,
    PROBE,
    RESET,
    RESET_WAIT,
    NVM_CHECK,
    CALIB,
    SLEEP,
    CONFIG,
    MODE,
    RUN,
    SAMPLE,
    CHECK,
  };

  void launch(uint32_t now_us);
  void complete(uint8_t status, uint32_t now_us, SensorEvent *event);
  void fail(uint8_t status, uint32_t now_us, SensorEvent *event);
  void next_candidate(uint32_t now_us, SensorEvent *event);
  void error(SensorEvent *event, uint8_t code, uint8_t detail, uint16_t count);
  bool transact(const uint8_t *data, uint8_t len, uint8_t read_len, uint32_t now_us);
  uint8_t ctrl_meas() const;
  uint8_t config() const;

  SensorSettings settings_;
  State state_;
  bool in_flight_;
  bool reconfigure_pending_;
  uint8_t candidate_;
  uint8_t address_;
  uint8_t model_;
  uint8_t chip_id_;
  uint8_t wrong_id_;
  uint8_t failures_;
  uint8_t nvm_tries_;
  uint8_t no_data_;
  uint16_t probe_failures_;
  uint16_t timeouts_;
  uint32_t wait_until_;
  uint32_t last_check_;
  uint32_t i2c_errors_;
  uint8_t buf_[BMP280_CALIB_LEN];
  Bmp280Calib calib_;
};

#endif
