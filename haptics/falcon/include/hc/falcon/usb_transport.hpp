#pragma once
/// @file usb_transport.hpp
/// Falcons on the USB bus through libusb-1.0 (FTDI-based: vendor 0x0403, product 0xCB48).
/// libusb stays inside usb_transport.cpp. Several Falcons may be attached at once; they are
/// numbered in bus order (index 0, 1, ...) or chosen by serial number.

#include "hc/falcon/transport.hpp"

#include <string>
#include <vector>

namespace hc::falcon {

/// One attached Falcon as seen by enumeration.
struct UsbFalconInfo {
  int index = 0;             ///< position among the Falcons found (bus order)
  int bus = 0;
  int address = 0;
  std::string port_path;     ///< e.g. "1-2.3"
  std::string serial;        ///< USB serial number ("" when it could not be read)
  bool accessible = false;   ///< we may open it (permissions, not claimed elsewhere)
  std::string problem;       ///< why not, and what to do
};

/// Lists attached Falcons. Real-time: no.
/// @throws hc::ResourceError if libusb cannot be initialised (message says what to check).
std::vector<UsbFalconInfo> list_usb_falcons();

/// Opens the Falcon with the given index (or serial, when `serial` is not empty): claims
/// interface 0 (detaching a kernel driver if one is bound), resets the FTDI and purges.
class UsbFalconProvider final : public TransportProvider {
 public:
  explicit UsbFalconProvider(int index = 0, std::string serial = {}) : index_(index), serial_(std::move(serial)) {}
  /// @throws hc::ResourceError: no Falcon at that index/serial (lists what is there), access
  ///         denied (points at the udev rule), interface busy (another program holds it).
  std::unique_ptr<Transport> open() override;
  std::string describe() const override;

 private:
  int index_;
  std::string serial_;
};

}  // namespace hc::falcon
