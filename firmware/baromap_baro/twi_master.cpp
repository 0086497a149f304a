#if defined(__AVR__)

#include "twi_master.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/delay.h>
#include <util/twi.h>

namespace {

volatile twi::Status state = twi::IDLE;
volatile uint8_t hw_status = 0;
uint8_t address = 0;
uint8_t write_buf[twi::MAX_WRITE];
uint8_t write_len = 0;
volatile uint8_t write_index = 0;
uint8_t *read_buf = 0;
uint8_t read_len = 0;
volatile uint8_t read_index = 0;
volatile bool reading = false;
uint32_t started_us = 0;
uint32_t timeout_us = 0;
uint32_t bit_rate_hz = 100000;

const uint8_t RUN = _BV(TWINT) | _BV(TWEN) | _BV(TWIE);

inline void finish(twi::Status result, bool send_stop) {
  hw_status = TW_STATUS;
  TWCR = send_stop ? (uint8_t)(_BV(TWINT) | _BV(TWEN) | _BV(TWSTO)) : (uint8_t)(_BV(TWINT) | _BV(TWEN));
  state = result;
}

void configure() {
  TWSR = 0;  // prescaler 1
  TWBR = (uint8_t)((F_CPU / bit_rate_hz - 16) / 2);
  TWCR = _BV(TWEN);
}

// A slave reset in the middle of a read may hold SDA low forever. Nine clocks let it finish
// its byte, then a STOP frees the bus (I2C specification, "bus clear"). About 100 us.
// The lines are open drain: a pin is only ever an input (pulled up) or driven low. The port
// bit is cleared before the pin becomes an output, never after, or the pin would drive the
// line high for a cycle against a slave holding it low.
void clear_bus() {
  const uint8_t SDA = _BV(PC4);
  const uint8_t SCL = _BV(PC5);
  TWCR = 0;
  DDRC &= (uint8_t)~(SDA | SCL);  // released: pulled up
  PORTC |= SDA | SCL;
  for (uint8_t i = 0; i < 9 && !(PINC & SDA); ++i) {
    PORTC &= (uint8_t)~SCL;
    DDRC |= SCL;  // SCL low
    _delay_us(5);
    DDRC &= (uint8_t)~SCL;
    PORTC |= SCL;  // released
    _delay_us(5);
  }
  // STOP: SDA low to high while SCL is high.
  PORTC &= (uint8_t)~SDA;
  DDRC |= SDA;
  _delay_us(5);
  DDRC &= (uint8_t)~SDA;
  PORTC |= SDA;
  _delay_us(5);
  configure();
}

}  // namespace

ISR(TWI_vect) {
  switch (TW_STATUS) {
    case TW_START:
    case TW_REP_START:
      TWDR = (uint8_t)((address << 1) | (reading ? TW_READ : TW_WRITE));
      TWCR = RUN;
      break;
    case TW_MT_SLA_ACK:
    case TW_MT_DATA_ACK:
      if (write_index < write_len) {
        TWDR = write_buf[write_index];
        write_index = (uint8_t)(write_index + 1);
        TWCR = RUN;
      } else if (read_len > 0) {
        reading = true;
        TWCR = RUN | _BV(TWSTA);
      } else {
        finish(twi::DONE, true);
      }
      break;
    case TW_MT_SLA_NACK:
    case TW_MR_SLA_NACK:
      finish(twi::ERR_ADDR_NACK, true);
      break;
    case TW_MT_DATA_NACK:
      finish(twi::ERR_DATA_NACK, true);
      break;
    case TW_MR_SLA_ACK:
      TWCR = read_len > 1 ? (uint8_t)(RUN | _BV(TWEA)) : RUN;
      break;
    case TW_MR_DATA_ACK:
      if (read_index < read_len) {
        read_buf[read_index] = TWDR;
        read_index = (uint8_t)(read_index + 1);
      }
      if (read_index >= read_len) {  // the slave sent more than asked: cannot happen
        finish(twi::ERR_BUS, true);
      } else {
        TWCR = (uint8_t)(read_index + 1 < read_len ? RUN | _BV(TWEA) : RUN);
      }
      break;
    case TW_MR_DATA_NACK:
      if (read_index < read_len) {
        read_buf[read_index] = TWDR;
        read_index = (uint8_t)(read_index + 1);
      }
      finish(read_index == read_len ? twi::DONE : twi::ERR_BUS, true);
      break;
    case TW_MT_ARB_LOST:
      finish(twi::ERR_BUS, false);
      break;
    default:  // TW_BUS_ERROR and anything unexpected
      finish(twi::ERR_BUS, true);
      break;
  }
}

namespace twi {

void begin(uint32_t hz) {
  bit_rate_hz = hz;
  PORTC |= _BV(PC4) | _BV(PC5);  // internal pull-ups; breakout boards add stronger ones
  configure();
}

bool start(uint8_t addr, const uint8_t *data, uint8_t len, uint8_t *buf, uint8_t rlen,
           uint32_t now_us, uint32_t limit_us) {
  if (state == BUSY || len > MAX_WRITE || (len == 0 && rlen == 0)) {
    return false;
  }
  // A STOP still being sent clears itself within a few microseconds; wait a bounded while.
  for (uint8_t spin = 0; spin < 200 && (TWCR & _BV(TWSTO)); ++spin) {
    _delay_us(1);
  }
  address = addr;
  for (uint8_t i = 0; i < len; ++i) write_buf[i] = data[i];
  write_len = len;
  write_index = 0;
  read_buf = buf;
  read_len = rlen;
  read_index = 0;
  reading = len == 0;
  started_us = now_us;
  timeout_us = limit_us;
  state = BUSY;
  TWCR = RUN | _BV(TWSTA);
  return true;
}

Status poll(uint32_t now_us) {
  Status s = state;
  if (s == BUSY) {
    if (now_us - started_us <= timeout_us) {
      return BUSY;
    }
    uint8_t sreg = SREG;
    cli();
    hw_status = TW_STATUS;
    TWCR = 0;  // no more TWI interrupts for this transaction
    state = IDLE;
    SREG = sreg;
    clear_bus();
    return ERR_TIMEOUT;
  }
  if (s != IDLE) {
    state = IDLE;
  }
  return s;
}

bool finished() { return state != IDLE && state != BUSY; }

uint8_t last_hw_status() { return hw_status; }

}  // namespace twi

#endif  // __AVR__
