#pragma once
/// @file transport.hpp
/// The byte pipe to one Falcon: FTDI vendor control requests plus bulk reads and writes of
/// payload bytes (the FTDI status bytes already stripped). Implemented over libusb-1.0
/// (usb_transport.hpp) and by the emulator (emulator.hpp). Calls return an IoStatus and never
/// throw, so the servo path can use them.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

namespace hc::falcon {

enum class IoStatus : std::uint8_t {
  kOk = 0,
  kTimeout,       ///< nothing arrived / could not send within the time-out
  kDisconnected,  ///< the device is gone (unplugged); this transport stays dead
  kError,         ///< any other transfer error
};

/// "ok", "timeout", "disconnected", "error". Real-time: yes.
const char* to_string(IoStatus status) noexcept;

class Transport {
 public:
  virtual ~Transport() = default;
  /// One FTDI vendor request (protocol.hpp, namespace ftdi). Real-time: as the transfer (≤ 1 s).
  virtual IoStatus control(std::uint8_t request, std::uint16_t value) noexcept = 0;
  /// Sends all of `bytes` within timeout_ms [ms].
  virtual IoStatus write(std::span<const std::uint8_t> bytes, int timeout_ms) noexcept = 0;
  /// Receives 1..buffer.size() payload bytes, waiting at most timeout_ms [ms]; kTimeout with
  /// received = 0 when none came.
  virtual IoStatus read(std::span<std::uint8_t> buffer, std::size_t& received, int timeout_ms) noexcept = 0;
  /// Human-readable identity (bus/address/serial or "emulator #n"). Real-time: no.
  virtual std::string describe() const = 0;
};

/// Opens transports to one chosen device, again after an unplug (reconnection).
class TransportProvider {
 public:
  virtual ~TransportProvider() = default;
  /// @throws hc::ResourceError naming the device and what to check when it cannot be opened.
  virtual std::unique_ptr<Transport> open() = 0;
  virtual std::string describe() const = 0;
};

/// Both purges (RX, TX). @return the first failing status. Real-time: no.
IoStatus ftdi_purge(Transport& t) noexcept;
/// Line set-up: latency timer [ms], baud divisor, 8N1, no flow control. Real-time: no.
IoStatus ftdi_configure(Transport& t, std::uint8_t latency_ms, std::uint16_t baud_divisor) noexcept;

}  // namespace hc::falcon
