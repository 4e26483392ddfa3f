#pragma once
/// @file firmware.hpp
/// Getting the Novint firmware running on a Falcon. The image is not ours to ship: the user
/// names it with the config key `falcon.firmware` or the environment variable
/// HAPTICLOUD_FALCON_FIRMWARE. Boot handshake facts from libnifalcon (BSD), re-derived:
/// purge, latency 16 ms, 9600 Bd 8N1, RTS low, DTR low then high; the probe kBootProbe must be
/// answered by kBootProbeReply (retried); then DTR low, upload baud, the start byte is echoed;
/// then every image byte is echoed back and checked; then run mode (latency 1 ms, run baud,
/// purge). Firmware is running when a zero command frame is answered by a valid status frame.
/// Everything here is non-real-time and used from open() and from reconnection.

#include "hc/falcon/transport.hpp"

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace hc::falcon {

inline constexpr const char* kFirmwareEnvVar = "HAPTICLOUD_FALCON_FIRMWARE";
inline constexpr const char* kFirmwareConfigKey = "falcon.firmware";

struct FirmwareOptions {
  int attempts = 3;            ///< whole boot-and-upload attempts before giving up, ≥ 1
  int probe_tries = 20;        ///< probe messages per attempt, ≥ 1
  int timeout_ms = 1000;       ///< per read of an echo or reply [ms]
  std::size_t chunk_bytes = 58; ///< bytes per upload write (≤ 62: one USB packet with status)
  int run_probe_tries = 5;     ///< zero frames sent to see whether firmware runs
};

/// What happened while getting the firmware running.
struct FirmwareReport {
  bool already_running = false;  ///< probe answered: nothing was loaded
  bool loaded = false;           ///< an upload succeeded
  int attempts = 0;              ///< upload attempts made
  std::string log;               ///< one line per attempt saying what failed
};

/// The firmware path: `configured` if not empty, else $HAPTICLOUD_FALCON_FIRMWARE.
/// @throws hc::ConfigError naming the key and the variable when neither is set.
std::filesystem::path resolve_firmware_path(const std::string& configured);
/// Reads the image. @throws hc::InputError naming the file if it is missing, unreadable, empty
/// or larger than 1 MiB.
std::vector<std::uint8_t> read_firmware_image(const std::filesystem::path& path);

/// Switches the line to run mode (latency 1 ms, run baud, 8N1, purge).
IoStatus enter_run_mode(Transport& t) noexcept;
/// Run mode, then zero command frames until a valid status frame answers (tries × timeout).
bool firmware_running(Transport& t, int tries, int timeout_ms) noexcept;
/// One boot handshake and upload with every echoed byte checked. @return "" on success, else
/// what failed (step, byte offset, expected and received values, transport status).
std::string upload_firmware_once(Transport& t, const std::vector<std::uint8_t>& image, const FirmwareOptions& options);
/// Skips loading when the firmware runs already; otherwise gets the image from `image_source`
/// (called only then) and tries options.attempts uploads. Leaves the line in run mode.
/// @throws hc::ResourceError with the whole report and what to try (replug, check the file,
///         check permissions) when every attempt failed; what image_source throws.
FirmwareReport ensure_firmware(Transport& t, const std::function<std::vector<std::uint8_t>()>& image_source,
                               const FirmwareOptions& options);

}  // namespace hc::falcon
