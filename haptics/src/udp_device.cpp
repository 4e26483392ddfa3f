#include "hc/haptics/udp_device.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <sstream>
#include <utility>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <unistd.h>

namespace hc::haptics {

namespace {

constexpr std::size_t kDatagramBytes = 48;
constexpr std::uint16_t kVersion = 1;

// Little-endian field access (the host is little-endian on every platform hapticloud builds
// for; memcpy keeps it free of alignment and aliasing assumptions).
template <class T>
T get(const unsigned char* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <class T>
void put(unsigned char* p, T v) {
  std::memcpy(p, &v, sizeof v);
}

}  // namespace

UdpDeviceOptions parse_udp_address(const std::string& host_port) {
  const std::size_t colon = host_port.rfind(':');
  UdpDeviceOptions o;
  if (colon == std::string::npos || colon == 0 || colon + 1 == host_port.size()) {
    throw ConfigError("udp device '" + host_port + "': expected HOST:PORT (e.g. udp:127.0.0.1:7700)");
  }
  o.host = host_port.substr(0, colon);
  const std::string port = host_port.substr(colon + 1);
  char* end = nullptr;
  const long p = std::strtol(port.c_str(), &end, 10);
  if (end == port.c_str() || *end != '\0' || p < 0 || p > 65535) {
    throw ConfigError("udp device '" + host_port + "': port '" + port + "' is not a number in 0..65535");
  }
  o.port = static_cast<int>(p);
  return o;
}

UdpDevice::UdpDevice(const Clock& clock, UdpDeviceOptions options)
    : HapticDevice(options.info), clock_(clock), o_(std::move(options)) {
  if (!(o_.timeout_s > 0.0) || o_.timeout_s > 10.0) {
    std::ostringstream s;
    s << "udp device: timeout " << o_.timeout_s << " s, expected (0, 10]";
    throw ConfigError(s.str());
  }
}

UdpDevice::~UdpDevice() { close(); }

void UdpDevice::do_open() {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_DGRAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* res = nullptr;
  const std::string where = o_.host + ":" + std::to_string(o_.port);
  if (const int rc = ::getaddrinfo(o_.host.c_str(), std::to_string(o_.port).c_str(), &hints, &res); rc != 0) {
    throw ResourceError("udp device " + where + ": " + ::gai_strerror(rc));
  }
  std::string why = "no address";
  for (addrinfo* a = res; a != nullptr; a = a->ai_next) {
    const int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) {
      why = std::strerror(errno);
      continue;
    }
    if (::bind(fd, a->ai_addr, a->ai_addrlen) != 0) {
      why = std::strerror(errno);
      ::close(fd);
      continue;
    }
    fd_ = fd;
    break;
  }
  ::freeaddrinfo(res);
  if (fd_ < 0) throw ResourceError("udp device: cannot bind " + where + ": " + why);
  sockaddr_storage bound{};
  socklen_t len = sizeof bound;
  if (::getsockname(fd_, reinterpret_cast<sockaddr*>(&bound), &len) == 0) {
    const int port = bound.ss_family == AF_INET6 ? ntohs(reinterpret_cast<sockaddr_in6*>(&bound)->sin6_port)
                                                 : ntohs(reinterpret_cast<sockaddr_in*>(&bound)->sin_port);
    bound_port_.store(port, std::memory_order_relaxed);
  }
  have_pose_ = false;
  peer_len_ = 0;
  out_seq_ = 0;
}

void UdpDevice::do_close() noexcept {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

DeviceStatus UdpDevice::do_read(DeviceReading& out) noexcept {
  const std::int64_t now = clock_.now_ns();
  unsigned char buf[kDatagramBytes + 1];
  for (;;) {
    sockaddr_storage from{};
    socklen_t from_len = sizeof from;
    const ssize_t n = ::recvfrom(fd_, buf, sizeof buf, 0, reinterpret_cast<sockaddr*>(&from), &from_len);
    if (n < 0) break;  // EAGAIN: nothing more waiting (or an error: the watchdog decides)
    if (static_cast<std::size_t>(n) != kDatagramBytes || std::memcmp(buf, "HCPI", 4) != 0 ||
        get<std::uint16_t>(buf + 4) != kVersion) {
      dropped_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    const std::uint32_t seq = get<std::uint32_t>(buf + 8);
    const Eigen::Vector3d p(get<double>(buf + 24), get<double>(buf + 32), get<double>(buf + 40));
    // A pose must be newer than the last one taken, unless the sender changed or went silent
    // past the timeout (a restarted client counts from 0 again).
    const bool same_sender = from_len == peer_len_ && std::memcmp(&from, &peer_, from_len) == 0;
    const bool silent = have_pose_ && static_cast<double>(now - last_rx_ns_) > o_.timeout_s * 1e9;
    const bool newer = !have_pose_ || !same_sender || silent || static_cast<std::int32_t>(seq - last_seq_) > 0;
    if (!p.allFinite() || !newer) {
      dropped_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    have_pose_ = true;
    last_seq_ = seq;
    buttons_ = get<std::uint32_t>(buf + 12);
    last_client_ns_ = get<std::int64_t>(buf + 16);
    position_m_ = p;
    last_rx_ns_ = now;
    peer_len_ = std::min<socklen_t>(from_len, sizeof peer_);
    std::memcpy(&peer_, &from, peer_len_);
  }
  out.position_m = position_m_;
  out.buttons = buttons_;
  out.time_ns = now;
  if (!have_pose_) return DeviceStatus::kNoData;
  if (static_cast<double>(now - last_rx_ns_) > o_.timeout_s * 1e9) return DeviceStatus::kIoError;
  return DeviceStatus::kOk;
}

DeviceStatus UdpDevice::do_write(const Eigen::Vector3d& force_n) noexcept {
  if (fd_ < 0 || peer_len_ == 0) return DeviceStatus::kOk;
  unsigned char buf[kDatagramBytes] = {};
  std::memcpy(buf, "HCFO", 4);
  put<std::uint16_t>(buf + 4, kVersion);
  buf[6] = static_cast<unsigned char>(state());
  put<std::uint32_t>(buf + 8, out_seq_++);
  put<std::uint32_t>(buf + 12, last_seq_);
  put<std::int64_t>(buf + 16, last_client_ns_);
  put<double>(buf + 24, force_n.x());
  put<double>(buf + 32, force_n.y());
  put<double>(buf + 40, force_n.z());
  if (::sendto(fd_, buf, sizeof buf, 0, reinterpret_cast<const sockaddr*>(&peer_), peer_len_) !=
      static_cast<ssize_t>(sizeof buf)) {
    send_failed_.fetch_add(1, std::memory_order_relaxed);
  }
  return DeviceStatus::kOk;
}

}  // namespace hc::haptics
