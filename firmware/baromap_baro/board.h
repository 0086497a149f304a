// The barometer board's main logic (AVR only): scheduling of samples and status frames,
// host commands, counters, LED. setup() and loop() of the sketch only call these two.
#ifndef BAROMAP_BOARD_H
#define BAROMAP_BOARD_H

void board_setup();
void board_loop();

#endif
