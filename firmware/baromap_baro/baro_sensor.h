// The barometer on I2C, as a non-blocking state machine (AVR only). At 0x76 and 0x77 it looks
// for a BMP280/BME280 (chip id register) and, where something else answers, for an MS5611
// (reset, PROM with a valid CRC-4). A BMP280 is soft-reset, its calibration read, then run in
// normal mode and its data registers read when a sample is due. An MS5611 has no continuous
// mode: the driver converts D2 and D1 back to back and a sample takes the latest pair.
// Every step is one I2C transaction started in one loop pass and collected in a later one;
// failures are counted, reported as events and retried, never waited out.
#ifndef BAROMAP_BARO_SENSOR_H
#define BAROMAP_BARO_SENSOR_H

#include <stdint.h>

#include "bmp280_math.h"
#include "ms5611_math.h"

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
  bool sampling() const { return state_ == SAMPLE || sample_requested_; }
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
    MS_RESET,
    MS_RESET_WAIT,
    MS_PROM,
    MS_CONVERT,
    MS_WAIT,
    MS_READ,
  };

  void launch(uint32_t now_us);
  void complete(uint8_t status, uint32_t now_us, SensorEvent *event);
  void fail(uint8_t status, uint32_t now_us, SensorEvent *event);
  void next_candidate(uint32_t now_us, SensorEvent *event);
  void complete_ms5611(uint32_t now_us, SensorEvent *event);
  uint8_t ms5611_osr_index() const;
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
  bool unrecognised_;     // something answered at an address but was no sensor we know
  bool ms_probe_;         // checking whether the device at candidate_ is an MS5611
  bool sample_requested_;  // MS5611: a sample was asked for; the next poll answers it
  bool ms_have_value_;
  bool ms_converting_d2_;
  uint8_t prom_index_;
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
  uint16_t prom_[MS5611_PROM_WORDS];
  uint32_t ms_d2_;
  uint32_t ms_pressure_q24_8_;
  int16_t ms_temperature_centi_;
};

#endif
