#if defined(__AVR__)

#include "baro_sensor.h"

#include "config.h"
#include "protocol.h"
#include "twi_master.h"

namespace {

const uint8_t ADDRESSES[2] = {0x76, 0x77};
const uint8_t REG_CALIB = 0x88;
const uint8_t REG_CHIP_ID = 0xD0;
const uint8_t REG_RESET = 0xE0;
const uint8_t REG_STATUS = 0xF3;
const uint8_t REG_CTRL_MEAS = 0xF4;
const uint8_t REG_CONFIG = 0xF5;
const uint8_t REG_DATA = 0xF7;
const uint8_t RESET_WORD = 0xB6;
const uint8_t STATUS_IM_UPDATE = 0x01;
const uint8_t MODE_NORMAL = 0x03;
const uint32_t STARTUP_US = 2000;  // data sheet: start-up time after reset 2 ms
const uint8_t NVM_TRIES = 10;

// MS5611 commands and timing (data sheet MS5611-01BA03).
const uint8_t MS_CMD_RESET = 0x1E;
const uint8_t MS_CMD_CONVERT_D1 = 0x40;  // + 2 * OSR index
const uint8_t MS_CMD_CONVERT_D2 = 0x50;
const uint8_t MS_CMD_ADC_READ = 0x00;
const uint8_t MS_CMD_PROM_READ = 0xA0;  // + 2 * word
const uint32_t MS_RELOAD_US = 3000;     // 2.8 ms after reset
// Maximum conversion time for OSR 256, 512, 1024, 2048, 4096, plus a little margin.
const uint16_t MS_CONVERSION_US[5] = {650, 1220, 2330, 4590, 9100};

// Register codes: 1, 2, 4, 8, 16 -> 1..5 (oversampling); 0, 2, 4, 8, 16 -> 0..4 (IIR).
uint8_t log2_code(uint8_t value) {
  uint8_t code = 0;
  while (value > 1) {
    value >>= 1;
    ++code;
  }
  return code;
}

}  // namespace

void BaroSensor::begin(const SensorSettings &settings, uint32_t now_us) {
  settings_ = settings;
  state_ = WAIT_PROBE;
  in_flight_ = false;
  reconfigure_pending_ = false;
  candidate_ = 0;
  address_ = 0;
  model_ = proto::SENSOR_NONE;
  chip_id_ = 0;
  wrong_id_ = 0;
  unrecognised_ = false;
  ms_probe_ = false;
  sample_requested_ = false;
  ms_have_value_ = false;
  ms_converting_d2_ = true;
  prom_index_ = 0;
  failures_ = 0;
  nvm_tries_ = 0;
  no_data_ = 0;
  probe_failures_ = 0;
  timeouts_ = 0;
  wait_until_ = now_us;
  last_check_ = now_us;
  i2c_errors_ = 0;
}

void BaroSensor::reconfigure(const SensorSettings &settings) {
  settings_ = settings;
  reconfigure_pending_ = true;
}

bool BaroSensor::running() const {
  return state_ == RUN || state_ == SAMPLE || state_ == CHECK || state_ == MS_CONVERT ||
         state_ == MS_WAIT || state_ == MS_READ;
}

uint8_t BaroSensor::protocol_state() const {
  if (running()) return proto::STATE_RUNNING;
  if (state_ == WAIT_PROBE || state_ == PROBE || ms_probe_) return proto::STATE_SEARCHING;
  return proto::STATE_CONFIGURING;
}

uint8_t BaroSensor::ms5611_osr_index() const { return log2_code(settings_.osrs_p); }  // 1..16 -> 0..4

uint8_t BaroSensor::ctrl_meas() const {
  return (uint8_t)((log2_code(settings_.osrs_t) + 1) << 5 | (log2_code(settings_.osrs_p) + 1) << 2 |
                   MODE_NORMAL);
}

uint8_t BaroSensor::config() const {
  // Standby 0.5 ms (t_sb = 0): the sensor measures back to back; the stream rate decides.
  return (uint8_t)(log2_code(settings_.iir_filter) << 2);
}

bool BaroSensor::transact(const uint8_t *data, uint8_t len, uint8_t read_len, uint32_t now_us) {
  uint8_t addr = state_ == PROBE || ms_probe_ ? ADDRESSES[candidate_] : address_;
  in_flight_ = twi::start(addr, data, len, buf_, read_len, now_us, I2C_TIMEOUT_US);
  return in_flight_;
}

bool BaroSensor::start_sample(uint32_t now_us) {
  if (model_ == proto::SENSOR_MS5611) {
    // The conversions run continuously; the sample is the latest pair, given at the next poll.
    if (!running() || sample_requested_) {
      return false;
    }
    sample_requested_ = true;
    return true;
  }
  if (state_ != RUN || in_flight_ || reconfigure_pending_) {
    return false;
  }
  state_ = SAMPLE;
  uint8_t reg = REG_DATA;
  if (!transact(&reg, 1, 6, now_us)) {
    state_ = RUN;
    return false;
  }
  return true;
}

void BaroSensor::launch(uint32_t now_us) {
  uint8_t cmd[2];
  switch (state_) {
    case WAIT_PROBE:
      if ((int32_t)(now_us - wait_until_) >= 0) {
        state_ = PROBE;
        candidate_ = 0;
        wrong_id_ = 0;
        unrecognised_ = false;
        ms_probe_ = false;
        ms_have_value_ = false;
        model_ = proto::SENSOR_NONE;
        chip_id_ = 0;
        launch(now_us);
      }
      break;
    case PROBE:
      cmd[0] = REG_CHIP_ID;
      transact(cmd, 1, 1, now_us);
      break;
    case RESET:
      cmd[0] = REG_RESET;
      cmd[1] = RESET_WORD;
      transact(cmd, 2, 0, now_us);
      break;
    case RESET_WAIT:
      if ((int32_t)(now_us - wait_until_) >= 0) {
        state_ = NVM_CHECK;
        nvm_tries_ = 0;
        launch(now_us);
      }
      break;
    case NVM_CHECK:
      if ((int32_t)(now_us - wait_until_) >= 0) {
        cmd[0] = REG_STATUS;
        transact(cmd, 1, 1, now_us);
      }
      break;
    case CALIB:
      cmd[0] = REG_CALIB;
      transact(cmd, 1, BMP280_CALIB_LEN, now_us);
      break;
    case SLEEP:
      cmd[0] = REG_CTRL_MEAS;
      cmd[1] = 0;  // sleep mode: only then are writes to config guaranteed to land
      transact(cmd, 2, 0, now_us);
      break;
    case CONFIG:
      cmd[0] = REG_CONFIG;
      cmd[1] = config();
      transact(cmd, 2, 0, now_us);
      break;
    case MODE:
      cmd[0] = REG_CTRL_MEAS;
      cmd[1] = ctrl_meas();
      transact(cmd, 2, 0, now_us);
      break;
    case RUN:
      if (reconfigure_pending_) {
        reconfigure_pending_ = false;
        state_ = SLEEP;
        launch(now_us);
      } else if (now_us - last_check_ >= MODE_CHECK_PERIOD_US) {
        // A sensor that lost power comes back in sleep mode and would answer forever with
        // stale data: check that our mode is still set.
        last_check_ = now_us;
        state_ = CHECK;
        cmd[0] = REG_CTRL_MEAS;
        if (!transact(cmd, 1, 1, now_us)) state_ = RUN;
      }
      break;
    case MS_RESET:
      cmd[0] = MS_CMD_RESET;
      transact(cmd, 1, 0, now_us);
      break;
    case MS_RESET_WAIT:
      if ((int32_t)(now_us - wait_until_) >= 0) {
        state_ = MS_PROM;
        prom_index_ = 0;
        launch(now_us);
      }
      break;
    case MS_PROM:
      cmd[0] = (uint8_t)(MS_CMD_PROM_READ + 2 * prom_index_);
      transact(cmd, 1, 2, now_us);
      break;
    case MS_CONVERT:
      reconfigure_pending_ = false;  // the OSR is taken from the settings at every conversion
      cmd[0] = (uint8_t)((ms_converting_d2_ ? MS_CMD_CONVERT_D2 : MS_CMD_CONVERT_D1) +
                         2 * ms5611_osr_index());
      transact(cmd, 1, 0, now_us);
      break;
    case MS_WAIT:
      if ((int32_t)(now_us - wait_until_) >= 0) {
        state_ = MS_READ;
        launch(now_us);
      }
      break;
    case MS_READ:
      cmd[0] = MS_CMD_ADC_READ;
      transact(cmd, 1, 3, now_us);
      break;
    default:
      break;
  }
}

void BaroSensor::poll(uint32_t now_us, SensorEvent *event) {
  event->kind = SensorEvent::NONE;
  if (sample_requested_) {
    sample_requested_ = false;
    if (ms_have_value_ && running()) {
      event->kind = SensorEvent::SAMPLE;
      event->pressure_q24_8 = ms_pressure_q24_8_;
      event->temperature_centi_c = ms_temperature_centi_;
    } else {
      event->kind = SensorEvent::SAMPLE_FAILED;  // no conversion pair yet
    }
    return;
  }
  if (in_flight_) {
    twi::Status status = twi::poll(now_us);
    if (status == twi::BUSY) {
      return;
    }
    in_flight_ = false;
    complete(status, now_us, event);
    return;
  }
  launch(now_us);
}

void BaroSensor::error(SensorEvent *event, uint8_t code, uint8_t detail, uint16_t count) {
  event->kind = SensorEvent::ERROR;
  event->code = code;
  event->detail = detail;
  event->count = count;
}

void BaroSensor::next_candidate(uint32_t now_us, SensorEvent *event) {
  ++candidate_;
  if (candidate_ < sizeof ADDRESSES) {
    return;  // the next pass probes the other address
  }
  if (probe_failures_ != 0xFFFF) ++probe_failures_;
  if (unrecognised_) {
    error(event, proto::ERR_WRONG_CHIP_ID, wrong_id_, probe_failures_);
  } else {
    error(event, proto::ERR_SENSOR_NOT_FOUND, 0, probe_failures_);
  }
  state_ = WAIT_PROBE;
  wait_until_ = now_us + PROBE_RETRY_US;
}

void BaroSensor::fail(uint8_t status, uint32_t now_us, SensorEvent *event) {
  if (ms_probe_) {
    // It was not an MS5611 after all (or it stopped answering while we asked): next address.
    ms_probe_ = false;
    state_ = PROBE;
    next_candidate(now_us, event);
    return;
  }
  ++i2c_errors_;
  if (failures_ != 0xFF) ++failures_;
  if (status == twi::ERR_TIMEOUT && timeouts_ != 0xFFFF) ++timeouts_;
  if (failures_ >= LOST_AFTER_FAILURES) {
    error(event, proto::ERR_SENSOR_LOST, twi::last_hw_status(), failures_);
    failures_ = 0;
    probe_failures_ = 0;
    state_ = WAIT_PROBE;
    wait_until_ = now_us;
    return;
  }
  if (status == twi::ERR_TIMEOUT) {
    error(event, proto::ERR_BUS_TIMEOUT, twi::last_hw_status(), timeouts_);
  } else if (state_ == SAMPLE) {
    event->kind = SensorEvent::SAMPLE_FAILED;
  }
  if (state_ == SAMPLE || state_ == CHECK) {
    state_ = RUN;  // the same step is retried on the next pass or sample
  }
}

void BaroSensor::complete(uint8_t status, uint32_t now_us, SensorEvent *event) {
  if (state_ == PROBE) {
    if (status == twi::DONE) {
      uint8_t id = buf_[0];
      if (id == 0x56 || id == 0x57 || id == 0x58 || id == 0x60) {
        address_ = ADDRESSES[candidate_];
        chip_id_ = id;
        model_ = id == 0x60 ? proto::SENSOR_BME280 : proto::SENSOR_BMP280;
        failures_ = 0;
        state_ = RESET;
        return;
      }
      // Something answered with no BMP280 chip id: an MS5611 has no such register. Reset it and
      // read its PROM; a valid CRC-4 says it is one.
      wrong_id_ = id;
      unrecognised_ = true;
      ms_probe_ = true;
      state_ = MS_RESET;
      return;
    }
    next_candidate(now_us, event);  // an empty address is not an I2C error
    return;
  }
  if (status != twi::DONE) {
    fail(status, now_us, event);
    return;
  }
  failures_ = 0;
  timeouts_ = 0;
  if (state_ >= MS_RESET) {
    complete_ms5611(now_us, event);
    return;
  }
  switch (state_) {
    case RESET:
      state_ = RESET_WAIT;
      wait_until_ = now_us + STARTUP_US;
      break;
    case NVM_CHECK:
      if (buf_[0] & STATUS_IM_UPDATE) {
        if (++nvm_tries_ >= NVM_TRIES) {
          fail(twi::ERR_BUS, now_us, event);
        }
        wait_until_ = now_us + 1000;
      } else {
        state_ = CALIB;
      }
      break;
    case CALIB:
      if (!bmp280_parse_calib(buf_, &calib_)) {
        error(event, proto::ERR_BAD_CALIBRATION, 0, 1);
        state_ = WAIT_PROBE;
        wait_until_ = now_us + PROBE_RETRY_US;
      } else {
        state_ = SLEEP;
      }
      break;
    case SLEEP:
      state_ = CONFIG;
      break;
    case CONFIG:
      state_ = MODE;
      break;
    case MODE:
      state_ = RUN;
      no_data_ = 0;
      probe_failures_ = 0;
      last_check_ = now_us;
      event->kind = SensorEvent::CONFIGURED;
      break;
    case CHECK:
      state_ = RUN;
      if (buf_[0] != ctrl_meas()) {
        error(event, proto::ERR_SENSOR_RESET, buf_[0], 1);
        state_ = RESET;
      }
      break;
    case SAMPLE: {
      state_ = RUN;
      int32_t adc_p = bmp280_adc20(buf_);
      int32_t adc_t = bmp280_adc20(buf_ + 3);
      if (adc_p == BMP280_ADC_SKIPPED || adc_t == BMP280_ADC_SKIPPED) {
        // No measurement yet (just configured) or the sensor was reset behind our back.
        if (++no_data_ >= NO_DATA_LIMIT) {
          error(event, proto::ERR_NO_DATA, 0, no_data_);
          no_data_ = 0;
          state_ = RESET;
        } else {
          event->kind = SensorEvent::SAMPLE_FAILED;
        }
        break;
      }
      no_data_ = 0;
      int32_t t_fine = bmp280_t_fine(calib_, adc_t);
      event->kind = SensorEvent::SAMPLE;
      event->temperature_centi_c = (int16_t)bmp280_temperature_centi(t_fine);
      event->pressure_q24_8 = bmp280_pressure_q24_8(calib_, t_fine, adc_p);
      break;
    }
    default:
      break;
  }
}

void BaroSensor::complete_ms5611(uint32_t now_us, SensorEvent *event) {
  switch (state_) {
    case MS_RESET:
      state_ = MS_RESET_WAIT;
      wait_until_ = now_us + MS_RELOAD_US;
      break;
    case MS_PROM:
      prom_[prom_index_] = (uint16_t)((uint16_t)buf_[0] << 8 | buf_[1]);
      if (++prom_index_ < MS5611_PROM_WORDS) {
        break;
      }
      if (!ms5611_prom_valid(prom_)) {
        if (ms_probe_) {
          ms_probe_ = false;
          state_ = PROBE;
          next_candidate(now_us, event);
        } else {
          error(event, proto::ERR_BAD_CALIBRATION, 0, 1);
          state_ = WAIT_PROBE;
          wait_until_ = now_us + PROBE_RETRY_US;
        }
        break;
      }
      ms_probe_ = false;
      address_ = ADDRESSES[candidate_];
      model_ = proto::SENSOR_MS5611;
      chip_id_ = 0;
      no_data_ = 0;
      probe_failures_ = 0;
      ms_have_value_ = false;
      ms_converting_d2_ = true;
      state_ = MS_CONVERT;
      event->kind = SensorEvent::CONFIGURED;
      break;
    case MS_CONVERT:
      state_ = MS_WAIT;
      wait_until_ = now_us + MS_CONVERSION_US[ms5611_osr_index()];
      break;
    case MS_READ: {
      uint32_t value = (uint32_t)buf_[0] << 16 | (uint32_t)buf_[1] << 8 | buf_[2];
      state_ = MS_CONVERT;
      if (value == 0) {
        // Read too early, or the sensor was power-cycled and lost the conversion.
        if (++no_data_ >= NO_DATA_LIMIT) {
          error(event, proto::ERR_NO_DATA, 0, no_data_);
          no_data_ = 0;
          ms_have_value_ = false;
          state_ = MS_RESET;
        }
        ms_converting_d2_ = true;
        break;
      }
      no_data_ = 0;
      if (ms_converting_d2_) {
        ms_d2_ = value;
        ms_converting_d2_ = false;
        break;
      }
      int32_t temperature = 0;
      ms5611_compensate(prom_, value, ms_d2_, &temperature, &ms_pressure_q24_8_);
      ms_temperature_centi_ = (int16_t)temperature;
      ms_have_value_ = true;
      ms_converting_d2_ = true;
      break;
    }
    default:
      break;
  }
}

#endif  // __AVR__
