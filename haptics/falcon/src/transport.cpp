#include "hc/falcon/transport.hpp"

#include "hc/falcon/protocol.hpp"

namespace hc::falcon {

const char* to_string(IoStatus status) noexcept {
  switch (status) {
    case IoStatus::kOk: return "ok";
    case IoStatus::kTimeout: return "timeout";
    case IoStatus::kDisconnected: return "disconnected";
    case IoStatus::kError: return "error";
  }
  return "unknown";
}

IoStatus ftdi_purge(Transport& t) noexcept {
  IoStatus s = t.control(ftdi::kReset, ftdi::kPurgeRx);
  if (s != IoStatus::kOk) return s;
  return t.control(ftdi::kReset, ftdi::kPurgeTx);
}

IoStatus ftdi_configure(Transport& t, std::uint8_t latency_ms, std::uint16_t baud_divisor) noexcept {
  IoStatus s = t.control(ftdi::kSetLatencyTimer, latency_ms);
  if (s == IoStatus::kOk) s = t.control(ftdi::kSetBaudRate, baud_divisor);
  if (s == IoStatus::kOk) s = t.control(ftdi::kSetData, ftdi::kLine8N1);
  if (s == IoStatus::kOk) s = t.control(ftdi::kSetFlowControl, 0);
  return s;
}

}  // namespace hc::falcon
