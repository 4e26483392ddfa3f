#pragma once
/// @file udp_device.hpp
/// A network device bridge (issue "Ecosystem"): `--device udp:HOST:PORT`. A rig driven by
/// another SDK (CHAI3D, Force Dimension's, 3D Systems' OpenHaptics, a ROS 2 node) sends the end
/// effector's position and buttons in datagrams to HOST:PORT; hapticloud renders the force with
/// its own servo loop and sends it back to the address the latest datagram came from. If no
/// datagram arrives for `timeout_s`, the read reports kIoError, so the servo loop faults the
/// device: zero force until the fault is reset (as the Falcon's watchdog).
///
/// Datagrams (docs/udp_bridge.md), little-endian, fixed size:
///   pose, client → hapticloud, 48 bytes:
///     0 char[4] "HCPI" | 4 u16 version = 1 | 6 u16 reserved = 0 | 8 u32 seq | 12 u32 buttons |
///     16 i64 client time [ns] | 24 f64 x [m] | 32 f64 y [m] | 40 f64 z [m]   (device frame)
///   force, hapticloud → client, 48 bytes:
///     0 char[4] "HCFO" | 4 u16 version = 1 | 6 u8 state (DeviceState) | 7 u8 reserved = 0 |
///     8 u32 seq (hapticloud's own, +1 per datagram) | 12 u32 echo_seq (the pose it answers) |
///     16 i64 echo of that pose's client time [ns] | 24 f64 fx [N] | 32 f64 fy [N] | 40 f64 fz [N]
/// A pose whose seq is not newer than the last one taken from the same sender (serial-number
/// arithmetic, RFC 1982; after a silence longer than the timeout or from a new sender any seq
/// is taken, so a restarted client is heard), of another size, magic or version, or with a
/// non-finite position is dropped and counted.
/// Before the first pose the read reports kNoData: the servo loop renders no force and keeps
/// its contact gate closed, so a session armed before its client starts does not take the
/// first pose as a jump from the origin.
/// The client's round-trip time is its own clock now minus the echoed client time.

#include "hc/haptics/clock.hpp"
#include "hc/haptics/device.hpp"

#include <atomic>
#include <cstdint>
#include <string>

#include <sys/socket.h>

namespace hc::haptics {

struct UdpDeviceOptions {
  std::string host = "127.0.0.1";  ///< local address to bind (0.0.0.0: every interface)
  int port = 7700;                 ///< local UDP port, 0 = any free one (bound_port() tells)
  double timeout_s = 0.1;          ///< silence after which a read reports kIoError [s], (0, 10]
  DeviceInfo info;                 ///< capabilities the servo loop uses (name set by the caller)
};

/// Parses "HOST:PORT" (the part after "udp:"). @throws hc::ConfigError naming the text.
UdpDeviceOptions parse_udp_address(const std::string& host_port);

class UdpDevice final : public HapticDevice {
 public:
  /// @throws hc::ConfigError for an invalid timeout or info.
  UdpDevice(const Clock& clock, UdpDeviceOptions options);
  ~UdpDevice() override;

  /// The bound port (after open()). Thread-safe.
  int bound_port() const noexcept { return bound_port_.load(std::memory_order_relaxed); }
  /// Poses dropped (stale, malformed), force datagrams that could not be sent. Thread-safe.
  std::uint64_t poses_dropped() const noexcept { return dropped_.load(std::memory_order_relaxed); }
  std::uint64_t sends_failed() const noexcept { return send_failed_.load(std::memory_order_relaxed); }

 protected:
  /// Binds a non-blocking UDP socket. @throws hc::ResourceError naming HOST:PORT and the
  /// reason (address in use, no such address).
  void do_open() override;
  void do_close() noexcept override;
  /// Takes the newest valid pose waiting (non-blocking). Before the first pose: the origin and
  /// kNoData; afterwards, more than timeout_s without one: the last pose and kIoError.
  DeviceStatus do_read(DeviceReading& out) noexcept override;
  /// Sends the force to the last pose's sender (nothing before the first pose).
  DeviceStatus do_write(const Eigen::Vector3d& force_n) noexcept override;

 private:
  const Clock& clock_;
  UdpDeviceOptions o_;
  int fd_ = -1;
  std::atomic<int> bound_port_{0};
  bool have_pose_ = false;
  std::uint32_t last_seq_ = 0;
  std::int64_t last_rx_ns_ = 0;
  std::int64_t last_client_ns_ = 0;
  std::uint32_t buttons_ = 0;
  Eigen::Vector3d position_m_ = Eigen::Vector3d::Zero();
  sockaddr_storage peer_{};
  unsigned peer_len_ = 0;
  std::uint32_t out_seq_ = 0;
  std::atomic<std::uint64_t> dropped_{0}, send_failed_{0};
};

}  // namespace hc::haptics
