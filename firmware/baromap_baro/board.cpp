#if defined(__AVR__)

#include "board.h"

#include <Arduino.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "baro_sensor.h"
#include "config.h"
#include "protocol.h"
#include "rx_framer.h"
#include "serial_port.h"
#include "twi_master.h"

// MCUSR before anything touches it: why the board (re)started. Reading it and switching the
// watchdog off must happen first thing after reset, or a watchdog reset loops forever.
uint8_t reset_cause __attribute__((section(".noinit")));
void save_reset_cause() __attribute__((naked, used, section(".init3")));
void save_reset_cause() {
  reset_cause = MCUSR;
  MCUSR = 0;
  wdt_disable();
}

namespace {

const uint8_t LED = _BV(PB5);  // pin 13

// The counters since reset are kept in the STATUS payload itself; its sensor fields
// (i2c_errors, sensor_state) are filled from the sensor when a STATUS goes out.
proto::Status counters;
BaroSensor sensor;
RxFramer framer;
SensorSettings settings;
uint8_t rate_hz;
uint32_t period_us;
uint32_t next_sample_us;
uint32_t next_status_us;
uint32_t identify_until_us;
bool identify_active;
bool sample_due;
bool sample_in_flight;
uint32_t sample_time_us;
bool hello_sent;
uint16_t seq_hello, seq_sample, seq_status, seq_error, seq_ack;
uint8_t wire[proto::MAX_WIRE];

void send(size_t len) {
  if (len != 0 && serial_port::write(wire, (uint8_t)len)) {
    ++counters.frames_sent;
  } else {
    ++counters.frames_dropped;
  }
}

void send_hello(uint32_t now) {
  proto::Hello h;
  h.protocol_minor = proto::VERSION_MINOR;
  h.fw_major = FW_MAJOR;
  h.fw_minor = FW_MINOR;
  h.fw_patch = FW_PATCH;
  h.sensor = sensor.model();
  h.chip_id = sensor.chip_id();
  h.i2c_address = sensor.address();
  h.rate_hz = rate_hz;
  h.osrs_p = settings.osrs_p;
  h.osrs_t = settings.osrs_t;
  h.iir_filter = settings.iir_filter;
  h.reset_cause = reset_cause & 0x0F;
  send(proto::encode_hello(seq_hello++, now, h, wire, sizeof wire));
  hello_sent = true;
}

void send_status(uint32_t now) {
  counters.i2c_errors = sensor.i2c_errors();
  counters.sensor_state = sensor.protocol_state();
  send(proto::encode_status(seq_status++, now, counters, wire, sizeof wire));
}

void send_error(uint32_t now, const SensorEvent &e) {
  proto::Error err = {e.code, e.detail, e.count};
  send(proto::encode_error(seq_error++, now, err, wire, sizeof wire));
}

void send_ack(uint32_t now, uint8_t command, uint16_t command_seq, uint8_t result) {
  proto::Ack a = {command, command_seq, result};
  send(proto::encode_ack(seq_ack++, now, a, wire, sizeof wire));
}

void set_rate(uint8_t hz, uint32_t now) {
  rate_hz = hz;
  period_us = 1000000UL / hz;
  next_sample_us = now + period_us;
}

void handle_frame(uint32_t now) {
  proto::Frame frame;
  switch (proto::parse_frame(framer.data(), framer.length(), &frame)) {
    case proto::PARSE_OK:
      break;
    case proto::PARSE_CRC:
      ++counters.rx_crc_errors;
      return;
    default:
      ++counters.rx_bad_frames;
      return;
  }
  ++counters.rx_frames;
#if defined(BAROMAP_TEST_HOOKS)
  // Test builds only (make hooks): hang the loop so a test can watch the watchdog reset us.
  if (frame.type == proto::TEST_HANG) {
    for (;;) {
    }
  }
#endif
  proto::Command cmd;
  proto::AckResult result = proto::validate_command(frame, &cmd);
  send_ack(now, frame.type, frame.seq, result);
  if (result != proto::ACK_OK) {
    return;
  }
  switch (cmd.type) {
    case proto::SET_RATE:
      set_rate(cmd.rate_hz, now);
      break;
    case proto::SET_OVERSAMPLING:
      settings.osrs_p = cmd.osrs_p;
      settings.osrs_t = cmd.osrs_t;
      settings.iir_filter = cmd.iir_filter;
      sensor.reconfigure(settings);
      break;
    case proto::IDENTIFY:
      send_hello(now);
      identify_active = true;
      identify_until_us = now + IDENTIFY_BLINK_US;
      break;
    default:
      break;
  }
}

// Every byte waiting is handled on every pass: the receive ring never fills while we sleep.
void drain_input(uint32_t now) {
  for (int16_t c = serial_port::read(); c >= 0; c = serial_port::read()) {
    ++counters.rx_bytes;
    switch (framer.push((uint8_t)c)) {
      case RxFramer::FRAME:
        handle_frame(now);
        break;
      case RxFramer::OVERSIZED:
        ++counters.rx_overflows;
        break;
      default:
        break;
    }
  }
  counters.rx_overflows += serial_port::take_overflows();
}

void handle_sensor(uint32_t now) {
  SensorEvent event;
  sensor.poll(now, &event);
  switch (event.kind) {
    case SensorEvent::SAMPLE: {
      proto::Sample s = {event.pressure_q24_8, event.temperature_centi_c};
      send(proto::encode_sample(seq_sample++, sample_time_us, s, wire, sizeof wire));
      sample_in_flight = false;
      break;
    }
    case SensorEvent::CONFIGURED:
      send_hello(now);
      break;
    case SensorEvent::ERROR:
      send_error(now, event);
      if (!hello_sent) {
        send_hello(now);  // the first search is over: say who we are, sensor or not
      }
      break;
    default:
      break;
  }
  if (sample_in_flight && event.kind != SensorEvent::SAMPLE && !sensor.sampling()) {
    sample_in_flight = false;  // the read failed (error, timeout, sensor lost, no data yet)
    ++counters.samples_missed;
  }
}

void schedule(uint32_t now) {
  if ((int32_t)(now - next_sample_us) >= 0) {
    if (sample_due) {
      ++counters.samples_missed;  // the previous slot never got its read
    }
    sample_due = true;
    next_sample_us += period_us;
    if ((int32_t)(now - next_sample_us) >= 0) {
      // More than a whole period late (a slow pass): skip the lost slots, count them.
      uint32_t late = (now - next_sample_us) / period_us + 1;
      counters.samples_missed += late;
      next_sample_us += late * period_us;
    }
  }
  if (sample_due && !sample_in_flight) {
    if (!sensor.running()) {
      sample_due = false;
      ++counters.samples_missed;
    } else if (sensor.start_sample(now)) {
      sample_due = false;
      sample_in_flight = true;
      sample_time_us = now;
    }
  }
  if ((int32_t)(now - next_status_us) >= 0) {
    next_status_us += STATUS_PERIOD_US;
    send_status(now);
  }
}

void update_led(uint32_t now) {
  bool on;
  if (identify_active) {
    if ((int32_t)(now - identify_until_us) >= 0) {
      identify_active = false;
    }
    on = ((now >> 17) & 1) != 0;  // about 4 Hz
  } else {
    on = sensor.running();
  }
  if (on) {
    PORTB |= LED;
  } else {
    PORTB &= (uint8_t)~LED;
  }
}

// Idle sleep until the next interrupt (timer 0 every 1.024 ms, UART, TWI): the loop stays
// responsive and the CPU (and the simulator) rests between passes.
void idle() {
  set_sleep_mode(SLEEP_MODE_IDLE);
  cli();
  if (!serial_port::rx_pending() && !twi::finished()) {
    sleep_enable();
    sei();  // the instruction after sei always runs: no wake-up can be lost in between
    sleep_cpu();
    sleep_disable();
  }
  sei();
}

}  // namespace

void board_setup() {
  wdt_enable(WDTO_500MS);
  DDRB |= LED;
  serial_port::begin(UART_BAUD);
  twi::begin(I2C_HZ);
  settings.osrs_p = DEFAULT_OSRS_P;
  settings.osrs_t = DEFAULT_OSRS_T;
  settings.iir_filter = DEFAULT_IIR_FILTER;
  uint32_t now = micros();
  set_rate(DEFAULT_RATE_HZ, now);
  next_status_us = now + STATUS_PERIOD_US;
  sensor.begin(settings, now);
  static const uint8_t flush = 0x00;  // ends whatever partial frame the host holds
  serial_port::write(&flush, 1);
}

void board_loop() {
  wdt_reset();
  uint32_t now = micros();
  drain_input(now);
  handle_sensor(now);
  schedule(now);
  update_led(now);
  idle();
}

#endif  // __AVR__
