#pragma once
/// @file protocol.hpp
/// The Novint Falcon's wire protocol: USB ids, the FTDI vendor control requests of its USB-serial
/// bridge, the boot-loader handshake bytes, and the 16-byte run-mode frames exchanged with the
/// Novint firmware (facts from libnifalcon (BSD), re-derived; no code taken from it).
///
/// Run-mode frame layout (both directions): byte 0 is '<', byte 15 is '>', bytes 1..14 each carry
/// one value v in [0, 0x7f] sent as the byte 0x41 + v ('A' + v).
///  - bytes 1..12: three signed 16-bit values, one per axis, as four 4-bit nibbles each, least
///    significant nibble first (axis i uses bytes 1 + 4i .. 4 + 4i). Host → device: motor
///    commands; device → host: encoder counts.
///  - byte 13, host → device: bit 0 = homing mode, bits 1..3 = LEDs (green 0x2, blue 0x4, red 0x8).
///  - byte 13, device → host: bits 0..3 = grip buttons, bits 4..6 = homed flag of axes 1..3.
///  - byte 14: zero ('A').
/// Everything here is pure and real-time safe.

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace hc::falcon {

inline constexpr std::uint16_t kFtdiVendorId = 0x0403;    ///< FTDI's USB vendor id
inline constexpr std::uint16_t kFalconProductId = 0xCB48;  ///< the Falcon's product id

/// FTDI vendor control requests (bmRequestType 0x40, wIndex 0) and their values.
namespace ftdi {
inline constexpr std::uint8_t kRequestType = 0x40;
inline constexpr std::uint8_t kReset = 0;            ///< value: kResetSio, kPurgeRx, kPurgeTx
inline constexpr std::uint8_t kModemControl = 1;     ///< value: kDtr*/kRts*
inline constexpr std::uint8_t kSetFlowControl = 2;   ///< value 0: no flow control
inline constexpr std::uint8_t kSetBaudRate = 3;      ///< value: baud divisor
inline constexpr std::uint8_t kSetData = 4;          ///< value: line properties
inline constexpr std::uint8_t kSetLatencyTimer = 9;  ///< value: milliseconds
inline constexpr std::uint16_t kResetSio = 0;
inline constexpr std::uint16_t kPurgeRx = 1;
inline constexpr std::uint16_t kPurgeTx = 2;
inline constexpr std::uint16_t kDtrHigh = 0x0101;
inline constexpr std::uint16_t kDtrLow = 0x0100;
inline constexpr std::uint16_t kRtsHigh = 0x0202;
inline constexpr std::uint16_t kRtsLow = 0x0200;
inline constexpr std::uint16_t kLine8N1 = 0x0008;       ///< 8 data bits, no parity, 1 stop bit
inline constexpr std::uint16_t kBaudBootProbe = 0x4138; ///< 9600 Bd: boot-loader probe
inline constexpr std::uint16_t kBaudUpload = 0x0015;    ///< about 140 kBd: firmware upload
inline constexpr std::uint16_t kBaudRun = 0x0002;       ///< run mode (fastest divisor used)
inline constexpr std::uint8_t kLatencyBootMs = 16;      ///< latency timer while booting [ms]
inline constexpr std::uint8_t kLatencyRunMs = 1;        ///< latency timer in run mode [ms]
inline constexpr std::uint8_t kEndpointOut = 0x02;      ///< bulk OUT endpoint
inline constexpr std::uint8_t kEndpointIn = 0x81;       ///< bulk IN endpoint
inline constexpr std::size_t kStatusBytes = 2;          ///< modem status bytes heading every IN packet
}  // namespace ftdi

/// Boot-loader handshake: at 9600 Bd with DTR raised, the probe is answered by the reply; then at
/// the upload rate with DTR low, the start byte is echoed, and every firmware byte after it too.
inline constexpr std::array<std::uint8_t, 3> kBootProbe{0x0a, 0x43, 0x0d};
inline constexpr std::array<std::uint8_t, 4> kBootProbeReply{0x0a, 0x44, 0x2c, 0x0d};
inline constexpr std::uint8_t kBootStart = 0x41;

inline constexpr std::size_t kFrameSize = 16;
using Frame = std::array<std::uint8_t, kFrameSize>;

/// LED bits of a command frame.
inline constexpr std::uint8_t kLedGreen = 0x2;
inline constexpr std::uint8_t kLedBlue = 0x4;
inline constexpr std::uint8_t kLedRed = 0x8;
inline constexpr std::uint8_t kAllAxesHomed = 0x7;

/// Host → device.
struct CommandFrame {
  std::array<std::int16_t, 3> motor{};  ///< motor commands (firmware units)
  std::uint8_t leds = 0;                ///< kLed* bits
  bool homing = false;                  ///< homing mode on
  bool operator==(const CommandFrame&) const = default;
};

/// Device → host.
struct StatusFrame {
  std::array<std::int16_t, 3> encoder{};  ///< encoder counts per axis
  std::uint8_t buttons = 0;               ///< grip buttons, bits 0..3
  std::uint8_t homed_mask = 0;            ///< bit i: axis i homed (bits 0..2)
  bool operator==(const StatusFrame&) const = default;
};

/// Encodes a command frame (unused LED bits are dropped). Real-time: yes.
Frame encode_command(const CommandFrame& command) noexcept;
/// Decodes 16 bytes; false (out untouched) unless delimiters and every field are valid.
bool decode_command(std::span<const std::uint8_t> bytes, CommandFrame& out) noexcept;
/// Encodes a status frame (buttons masked to 4 bits, homed to 3). Real-time: yes.
Frame encode_status(const StatusFrame& status) noexcept;
/// Decodes 16 bytes; false (out untouched) unless delimiters and every field are valid.
bool decode_status(std::span<const std::uint8_t> bytes, StatusFrame& out) noexcept;

/// Finds frames in a byte stream that may hold garbage, cut frames or several frames at once.
/// A frame starts at '<'; 16 bytes later it must end with '>' and its body must be valid
/// (`Direction` picks the body check), otherwise the search restarts at the next '<' after the
/// bad start. Keeps the newest good frame. Fixed storage; real-time: yes.
class FrameAssembler {
 public:
  enum class Direction : std::uint8_t { kFromDevice = 0, kFromHost };
  explicit FrameAssembler(Direction direction = Direction::kFromDevice) noexcept : direction_(direction) {}
  /// Feeds bytes. @return the number of good frames completed by them.
  std::size_t push(std::span<const std::uint8_t> bytes) noexcept;
  /// The newest good frame not yet taken. @return false when none arrived since the last take.
  bool take(Frame& out) noexcept;
  void reset() noexcept;
  std::uint64_t good_frames() const noexcept { return good_; }
  std::uint64_t bad_frames() const noexcept { return bad_; }         ///< 16 bytes that were not a frame
  std::uint64_t skipped_bytes() const noexcept { return skipped_; }  ///< bytes outside any frame

 private:
  void push_byte(std::uint8_t b) noexcept;
  bool valid(const Frame& f) const noexcept;
  Direction direction_;
  Frame pending_{};
  std::size_t size_ = 0;
  Frame newest_{};
  bool has_newest_ = false;
  std::uint64_t good_ = 0, bad_ = 0, skipped_ = 0;
};

}  // namespace hc::falcon
