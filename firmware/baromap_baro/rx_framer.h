// Collects received bytes into one COBS frame at a time, bounded by the protocol's maximum
// encoded length: a longer run without 0x00 is counted once and skipped up to the next 0x00.
// Plain C++ for the host tests.
#ifndef BAROMAP_RX_FRAMER_H
#define BAROMAP_RX_FRAMER_H

#include <stdint.h>

#include "protocol.h"

class RxFramer {
 public:
  enum Event : uint8_t { NONE = 0, FRAME, OVERSIZED };

  RxFramer() : len_(0), skipping_(false) {}

  // Feed one byte. FRAME: a complete non-empty frame is in data()/length() until the next
  // push(). OVERSIZED: the current run just passed the maximum length (reported once per run).
  Event push(uint8_t byte);

  const uint8_t *data() const { return buf_; }
  uint8_t length() const { return len_ready_; }

 private:
  uint8_t buf_[proto::MAX_ENCODED];
  uint8_t len_;
  uint8_t len_ready_ = 0;
  bool skipping_;
};

#endif
