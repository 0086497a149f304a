#include "rx_framer.h"

RxFramer::Event RxFramer::push(uint8_t byte) {
  if (byte == 0x00) {
    bool had_frame = !skipping_ && len_ > 0;
    len_ready_ = had_frame ? len_ : 0;
    len_ = 0;
    skipping_ = false;
    return had_frame ? FRAME : NONE;
  }
  if (skipping_) {
    return NONE;
  }
  if (len_ >= proto::MAX_ENCODED) {
    skipping_ = true;
    len_ = 0;
    return OVERSIZED;
  }
  buf_[len_++] = byte;
  return NONE;
}
