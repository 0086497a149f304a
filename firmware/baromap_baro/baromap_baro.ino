// baromap barometer board: BMP280 on I2C -> framed binary samples on the USB serial port.
// Protocol: firmware/PROTOCOL.md. Build: `make -C firmware` or the Arduino IDE / arduino-cli
// (board Arduino Uno or Nano, ATmega328P). All logic lives in board.cpp and its helpers.

#include "board.h"

void setup() { board_setup(); }

void loop() { board_loop(); }
