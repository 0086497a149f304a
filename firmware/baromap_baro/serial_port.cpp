#if defined(__AVR__)

#include "serial_port.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

namespace {

const uint8_t RX_SIZE = 64;  // power of two
const uint8_t RX_MASK = RX_SIZE - 1;
// 256 bytes with 8-bit indices: the wrap is free. Holds one of each frame type at once.
uint8_t tx_buf[256];
volatile uint8_t tx_head = 0;  // written by write(), read by the ISR
volatile uint8_t tx_tail = 0;  // written by the ISR
uint8_t rx_buf[RX_SIZE];
volatile uint8_t rx_head = 0;  // written by the ISR
volatile uint8_t rx_tail = 0;
volatile uint8_t rx_overflows = 0;

}  // namespace

ISR(USART_RX_vect) {
  uint8_t status = UCSR0A;  // read before UDR0: the error flags belong to this byte
  uint8_t byte = UDR0;
  if (status & _BV(DOR0)) {
    if (rx_overflows != 0xFF) ++rx_overflows;
  }
  uint8_t next = (uint8_t)((rx_head + 1) & RX_MASK);
  if (next == rx_tail) {
    if (rx_overflows != 0xFF) ++rx_overflows;
    return;
  }
  rx_buf[rx_head] = byte;
  rx_head = next;
}

ISR(USART_UDRE_vect) {
  uint8_t tail = tx_tail;
  if (tail == tx_head) {
    UCSR0B &= (uint8_t)~_BV(UDRIE0);
    return;
  }
  UDR0 = tx_buf[tail];
  tx_tail = (uint8_t)(tail + 1);
}

namespace serial_port {

void begin(uint32_t baud) {
  // Double speed mode: 16 MHz / (8 * (16 + 1)) = 117647 baud for 115200 (+2.1 %).
  uint16_t ubrr = (uint16_t)((F_CPU / 4 / baud - 1) / 2);
  UCSR0A = _BV(U2X0);
  UBRR0H = (uint8_t)(ubrr >> 8);
  UBRR0L = (uint8_t)ubrr;
  UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);  // 8N1
  UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

int16_t read() {
  uint8_t tail = rx_tail;
  if (tail == rx_head) {
    return -1;
  }
  uint8_t byte = rx_buf[tail];
  rx_tail = (uint8_t)((tail + 1) & RX_MASK);
  return byte;
}

bool rx_pending() { return rx_tail != rx_head; }

uint8_t take_overflows() {
  uint8_t n;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    n = rx_overflows;
    rx_overflows = 0;
  }
  return n;
}

bool write(const uint8_t *data, uint8_t len) {
  uint8_t head = tx_head;
  uint8_t free_bytes = (uint8_t)(tx_tail - head - 1);  // one slot stays empty
  if (len > free_bytes) {
    return false;
  }
  for (uint8_t i = 0; i < len; ++i) {
    tx_buf[head++] = data[i];
  }
  tx_head = head;  // publish only once every byte is in place
  UCSR0B |= _BV(UDRIE0);
  return true;
}

}  // namespace serial_port

#endif  // __AVR__
