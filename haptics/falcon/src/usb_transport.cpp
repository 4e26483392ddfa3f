// Falcon transport over libusb-1.0 (FTDI request codes and endpoints: facts from libnifalcon (BSD),
// re-derived; see protocol.hpp).
#include "hc/falcon/usb_transport.hpp"

#include "hc/common/error.hpp"
#include "hc/falcon/protocol.hpp"
#include "hc/haptics/clock.hpp"

#include <libusb.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <mutex>

namespace hc::falcon {
namespace {

libusb_context* context() {
  static std::once_flag once;
  static libusb_context* ctx = nullptr;
  static int rc = 0;
  std::call_once(once, [] { rc = libusb_init(&ctx); });
  if (rc != 0) {
    throw ResourceError(std::string("falcon: libusb_init failed: ") + libusb_error_name(rc) +
                        " (is /dev/bus/usb available? in a container, pass the USB bus through)");
  }
  return ctx;
}

// Every libusb error other than a time-out or a vanished device is kError; FalconDevice takes the
// link down after FalconConfig::max_consecutive_io_errors of them in a row and reconnects.
IoStatus status_of(int rc) noexcept {
  switch (rc) {
    case LIBUSB_SUCCESS: return IoStatus::kOk;
    case LIBUSB_ERROR_TIMEOUT: return IoStatus::kTimeout;
    case LIBUSB_ERROR_NO_DEVICE: return IoStatus::kDisconnected;
    default: return IoStatus::kError;
  }
}

std::string port_path_of(libusb_device* dev) {
  std::array<std::uint8_t, 8> ports{};
  const int n = libusb_get_port_numbers(dev, ports.data(), static_cast<int>(ports.size()));
  std::string p = std::to_string(libusb_get_bus_number(dev));
  for (int i = 0; i < n; ++i) {
    p.push_back(i == 0 ? '-' : '.');
    p.append(std::to_string(ports[static_cast<std::size_t>(i)]));
  }
  return p;
}

struct DeviceList {
  libusb_device** list = nullptr;
  ssize_t count = 0;
  DeviceList() {
    count = libusb_get_device_list(context(), &list);
    if (count < 0) throw ResourceError(std::string("falcon: cannot list USB devices: ") + libusb_error_name(static_cast<int>(count)));
  }
  ~DeviceList() { libusb_free_device_list(list, 1); }
  DeviceList(const DeviceList&) = delete;
  DeviceList& operator=(const DeviceList&) = delete;
};

bool is_falcon(libusb_device* dev) {
  libusb_device_descriptor d{};
  return libusb_get_device_descriptor(dev, &d) == 0 && d.idVendor == kFtdiVendorId && d.idProduct == kFalconProductId;
}

std::string serial_of(libusb_device* dev, libusb_device_handle* h) {
  libusb_device_descriptor d{};
  if (libusb_get_device_descriptor(dev, &d) != 0 || d.iSerialNumber == 0) return {};
  std::array<unsigned char, 128> s{};
  const int n = libusb_get_string_descriptor_ascii(h, d.iSerialNumber, s.data(), static_cast<int>(s.size()));
  return n > 0 ? std::string(reinterpret_cast<const char*>(s.data()), static_cast<std::size_t>(n)) : std::string();
}

std::string access_hint(int rc) {
  if (rc == LIBUSB_ERROR_ACCESS) {
    return "permission denied: install udev/99-novint-falcon.rules (see README, 'Novint Falcon') and replug";
  }
  if (rc == LIBUSB_ERROR_BUSY) return "busy: another program has claimed the Falcon";
  return std::string("cannot open: ") + libusb_error_name(rc);
}

class UsbTransport final : public Transport {
 public:
  UsbTransport(libusb_device_handle* h, std::string name, int packet) : h_(h), name_(std::move(name)), packet_(packet) {}
  ~UsbTransport() override {
    libusb_release_interface(h_, 0);
    libusb_close(h_);
  }
  UsbTransport(const UsbTransport&) = delete;
  UsbTransport& operator=(const UsbTransport&) = delete;

  IoStatus control(std::uint8_t request, std::uint16_t value) noexcept override {
    if (dead_) return IoStatus::kDisconnected;
    const int rc = libusb_control_transfer(h_, ftdi::kRequestType, request, value, 0, nullptr, 0, 1000);
    return note(rc < 0 ? status_of(rc) : IoStatus::kOk);
  }

  IoStatus write(std::span<const std::uint8_t> bytes, int timeout_ms) noexcept override {
    if (dead_) return IoStatus::kDisconnected;
    std::size_t sent = 0;
    while (sent < bytes.size()) {
      int done = 0;
      // libusb takes a non-const buffer for both directions; OUT transfers do not write to it.
      auto* p = const_cast<unsigned char*>(bytes.data() + sent);
      const int rc = libusb_bulk_transfer(h_, ftdi::kEndpointOut, p, static_cast<int>(bytes.size() - sent), &done,
                                          static_cast<unsigned>(std::max(1, timeout_ms)));
      sent += static_cast<std::size_t>(std::max(0, done));
      if (rc != 0 && sent < bytes.size()) return note(status_of(rc));
    }
    return IoStatus::kOk;
  }

  IoStatus read(std::span<std::uint8_t> out, std::size_t& received, int timeout_ms) noexcept override {
    received = 0;
    if (dead_) return IoStatus::kDisconnected;
    const std::int64_t deadline = haptics::monotonic_now_ns() + std::int64_t{std::max(1, timeout_ms)} * 1000000;
    while (true) {
      if (pending_size_ > 0) {
        const std::size_t n = std::min(out.size(), pending_size_);
        std::memcpy(out.data(), pending_.data(), n);
        std::memmove(pending_.data(), pending_.data() + n, pending_size_ - n);
        pending_size_ -= n;
        received = n;
        return IoStatus::kOk;
      }
      const std::int64_t left_ms = (deadline - haptics::monotonic_now_ns()) / 1000000;
      if (left_ms < 0) return IoStatus::kTimeout;
      int got = 0;
      const int rc = libusb_bulk_transfer(h_, ftdi::kEndpointIn, raw_.data(), static_cast<int>(raw_.size()), &got,
                                          static_cast<unsigned>(std::max<std::int64_t>(1, left_ms)));
      // Every IN packet starts with the FTDI's two modem status bytes: strip them.
      for (int at = 0; at < got; at += packet_) {
        const int len = std::min(packet_, got - at);
        for (int i = static_cast<int>(ftdi::kStatusBytes); i < len && pending_size_ < pending_.size(); ++i) {
          pending_[pending_size_++] = raw_[static_cast<std::size_t>(at + i)];
        }
      }
      if (rc != 0 && rc != LIBUSB_ERROR_TIMEOUT && pending_size_ == 0) return note(status_of(rc));
      if (rc == LIBUSB_ERROR_TIMEOUT && pending_size_ == 0) return IoStatus::kTimeout;
    }
  }

  std::string describe() const override { return name_; }

 private:
  IoStatus note(IoStatus s) noexcept {
    if (s == IoStatus::kDisconnected) dead_ = true;
    return s;
  }
  libusb_device_handle* h_;
  std::string name_;
  int packet_;
  bool dead_ = false;
  std::array<std::uint8_t, 512> raw_{};
  std::array<std::uint8_t, 1024> pending_{};
  std::size_t pending_size_ = 0;
};

}  // namespace

std::vector<UsbFalconInfo> list_usb_falcons() {
  DeviceList devs;
  std::vector<UsbFalconInfo> out;
  for (ssize_t i = 0; i < devs.count; ++i) {
    libusb_device* dev = devs.list[i];
    if (!is_falcon(dev)) continue;
    UsbFalconInfo info;
    info.index = static_cast<int>(out.size());
    info.bus = libusb_get_bus_number(dev);
    info.address = libusb_get_device_address(dev);
    info.port_path = port_path_of(dev);
    libusb_device_handle* h = nullptr;
    const int rc = libusb_open(dev, &h);
    if (rc == 0) {
      info.serial = serial_of(dev, h);
      info.accessible = true;
      libusb_close(h);
    } else {
      info.problem = access_hint(rc);
    }
    out.push_back(std::move(info));
  }
  return out;
}

std::string UsbFalconProvider::describe() const {
  return serial_.empty() ? "USB Falcon #" + std::to_string(index_) : "USB Falcon serial " + serial_;
}

std::unique_ptr<Transport> UsbFalconProvider::open() {
  DeviceList devs;
  int seen = 0;
  std::string found_list;
  for (ssize_t i = 0; i < devs.count; ++i) {
    libusb_device* dev = devs.list[i];
    if (!is_falcon(dev)) continue;
    const int my_index = seen++;
    found_list += " #" + std::to_string(my_index) + " at " + port_path_of(dev);
    libusb_device_handle* h = nullptr;
    if (serial_.empty() && my_index != index_) continue;
    int rc = libusb_open(dev, &h);
    if (rc != 0) {
      if (!serial_.empty()) continue;
      throw ResourceError("falcon " + describe() + " at " + port_path_of(dev) + ": " + access_hint(rc));
    }
    if (!serial_.empty() && serial_of(dev, h) != serial_) {
      libusb_close(h);
      continue;
    }
    libusb_set_auto_detach_kernel_driver(h, 1);
    rc = libusb_claim_interface(h, 0);
    if (rc != 0) {
      libusb_close(h);
      throw ResourceError("falcon " + describe() + " at " + port_path_of(dev) + ": cannot claim interface 0: " + access_hint(rc));
    }
    int packet = libusb_get_max_packet_size(dev, ftdi::kEndpointIn);
    if (packet <= static_cast<int>(ftdi::kStatusBytes)) packet = 64;
    auto t = std::make_unique<UsbTransport>(h, "USB Falcon #" + std::to_string(my_index) + " at " + port_path_of(dev), packet);
    IoStatus s = t->control(ftdi::kReset, ftdi::kResetSio);
    if (s == IoStatus::kOk) s = ftdi_purge(*t);
    if (s != IoStatus::kOk) {
      throw ResourceError("falcon " + t->describe() + ": FTDI reset/purge failed (" + to_string(s) + "); replug the device");
    }
    return t;
  }
  throw ResourceError("falcon: " + describe() + " not found (Falcons attached:" +
                      (found_list.empty() ? std::string(" none") : found_list) +
                      "); check the USB cable and the power supply, and `hapticloud devices`");
}

}  // namespace hc::falcon
