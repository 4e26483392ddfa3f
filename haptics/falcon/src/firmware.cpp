// Firmware boot and upload (handshake facts from libnifalcon (BSD), re-derived; see firmware.hpp).
#include "hc/falcon/firmware.hpp"

#include "hc/common/error.hpp"
#include "hc/falcon/protocol.hpp"

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <sstream>

namespace hc::falcon {
namespace {

std::string hex(unsigned v) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "0x%02x", v & 0xFFU);
  return buf;
}

/// Reads exactly out.size() bytes (several reads), each read waiting at most timeout_ms.
IoStatus read_exact(Transport& t, std::span<std::uint8_t> out, std::size_t& got, int timeout_ms) {
  got = 0;
  while (got < out.size()) {
    std::size_t n = 0;
    const IoStatus s = t.read(out.subspan(got), n, timeout_ms);
    if (s != IoStatus::kOk) return s;
    got += n;
  }
  return IoStatus::kOk;
}

}  // namespace

std::filesystem::path resolve_firmware_path(const std::string& configured) {
  if (!configured.empty()) return configured;
  const char* env = std::getenv(kFirmwareEnvVar);
  if (env != nullptr && *env != '\0') return env;
  throw ConfigError(std::string("falcon: the firmware is not running and no firmware image is given: set the config key '") +
                    kFirmwareConfigKey + "' or the environment variable " + kFirmwareEnvVar +
                    " to the path of the Novint firmware file (e.g. test_firmware.bin / nVent firmware from the "
                    "Novint driver package; it is not shipped with hapticloud)");
}

std::vector<std::uint8_t> read_firmware_image(const std::filesystem::path& path) {
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) throw InputError("falcon firmware '" + path.string() + "': cannot read it (" + ec.message() + ")");
  if (size == 0 || size > (1U << 20)) {
    throw InputError("falcon firmware '" + path.string() + "': size " + std::to_string(size) +
                     " bytes, expected 1 byte .. 1 MiB (is this the Novint firmware image?)");
  }
  std::ifstream in(path, std::ios::binary);
  std::vector<std::uint8_t> image(static_cast<std::size_t>(size));
  if (!in.read(reinterpret_cast<char*>(image.data()), static_cast<std::streamsize>(size))) {
    throw InputError("falcon firmware '" + path.string() + "': read failed");
  }
  return image;
}

IoStatus enter_run_mode(Transport& t) noexcept {
  const IoStatus s = ftdi_configure(t, ftdi::kLatencyRunMs, ftdi::kBaudRun);
  if (s != IoStatus::kOk) return s;
  return ftdi_purge(t);
}

bool firmware_running(Transport& t, int tries, int timeout_ms) noexcept {
  if (enter_run_mode(t) != IoStatus::kOk) return false;
  const Frame zero = encode_command(CommandFrame{});
  FrameAssembler assembler;
  std::array<std::uint8_t, 64> buf{};
  for (int k = 0; k < tries; ++k) {
    if (t.write(zero, timeout_ms) != IoStatus::kOk) return false;
    std::size_t n = 0;
    const IoStatus s = t.read(buf, n, timeout_ms);
    if (s == IoStatus::kDisconnected || s == IoStatus::kError) return false;
    if (s == IoStatus::kOk && assembler.push(std::span<const std::uint8_t>(buf.data(), n)) > 0) return true;
  }
  return false;
}

std::string upload_firmware_once(Transport& t, const std::vector<std::uint8_t>& image, const FirmwareOptions& o) {
  const auto fail = [](const std::string& step, IoStatus s) { return step + " (" + to_string(s) + ")"; };
  IoStatus s = ftdi_purge(t);
  if (s != IoStatus::kOk) return fail("purge", s);
  s = ftdi_configure(t, ftdi::kLatencyBootMs, ftdi::kBaudBootProbe);
  if (s == IoStatus::kOk) s = t.control(ftdi::kModemControl, ftdi::kRtsLow);
  if (s == IoStatus::kOk) s = t.control(ftdi::kModemControl, ftdi::kDtrLow);
  if (s == IoStatus::kOk) s = t.control(ftdi::kModemControl, ftdi::kDtrHigh);
  if (s != IoStatus::kOk) return fail("line set-up for the boot loader", s);

  // Probe: the reply may come with one leading zero byte on some hosts.
  bool answered = false;
  std::string last;
  for (int k = 0; k < std::max(1, o.probe_tries) && !answered; ++k) {
    s = t.write(kBootProbe, o.timeout_ms);
    if (s != IoStatus::kOk) return fail("boot probe write", s);
    std::array<std::uint8_t, 64> buf{};
    std::size_t n = 0;
    s = t.read(buf, n, o.timeout_ms);
    if (s == IoStatus::kDisconnected || s == IoStatus::kError) return fail("boot probe read", s);
    std::size_t off = (n == kBootProbeReply.size() + 1 && buf[0] == 0x00) ? 1 : 0;
    answered = n - off == kBootProbeReply.size() &&
               std::equal(kBootProbeReply.begin(), kBootProbeReply.end(), buf.begin() + static_cast<std::ptrdiff_t>(off));
    if (!answered) last = s == IoStatus::kTimeout ? "no reply" : std::to_string(n) + " unexpected bytes";
  }
  if (!answered) return "boot loader did not answer the probe after " + std::to_string(o.probe_tries) + " tries (" + last + ")";

  s = t.control(ftdi::kModemControl, ftdi::kDtrLow);
  if (s == IoStatus::kOk) s = t.control(ftdi::kSetBaudRate, ftdi::kBaudUpload);
  if (s != IoStatus::kOk) return fail("switch to the upload rate", s);
  const std::array<std::uint8_t, 1> start{kBootStart};
  s = t.write(start, o.timeout_ms);
  if (s != IoStatus::kOk) return fail("start byte write", s);
  std::array<std::uint8_t, 1> echo{};
  std::size_t got = 0;
  s = read_exact(t, echo, got, o.timeout_ms);
  if (s != IoStatus::kOk) return fail("start byte echo", s);
  if (echo[0] != kBootStart) return "start byte echo: expected " + hex(kBootStart) + ", received " + hex(echo[0]);

  const std::size_t chunk = std::clamp<std::size_t>(o.chunk_bytes, 1, 62);
  std::vector<std::uint8_t> back(chunk);
  for (std::size_t at = 0; at < image.size(); at += chunk) {
    const std::size_t n = std::min(chunk, image.size() - at);
    const std::span<const std::uint8_t> part(image.data() + at, n);
    s = t.write(part, o.timeout_ms);
    if (s != IoStatus::kOk) return fail("upload write at byte " + std::to_string(at), s);
    s = read_exact(t, std::span<std::uint8_t>(back.data(), n), got, o.timeout_ms);
    if (s != IoStatus::kOk) {
      return fail("echo of byte " + std::to_string(at + got) + " of " + std::to_string(image.size()), s);
    }
    for (std::size_t i = 0; i < n; ++i) {
      if (back[i] != part[i]) {
        return "echo mismatch at byte " + std::to_string(at + i) + " of " + std::to_string(image.size()) + ": sent " +
               hex(part[i]) + ", received " + hex(back[i]);
      }
    }
  }
  s = enter_run_mode(t);
  if (s != IoStatus::kOk) return fail("switch to run mode", s);
  return {};
}

FirmwareReport ensure_firmware(Transport& t, const std::function<std::vector<std::uint8_t>()>& image_source,
                               const FirmwareOptions& o) {
  FirmwareReport report;
  if (firmware_running(t, std::max(1, o.run_probe_tries), o.timeout_ms)) {
    report.already_running = true;
    return report;
  }
  const std::vector<std::uint8_t> image = image_source();
  for (int k = 0; k < std::max(1, o.attempts); ++k) {
    ++report.attempts;
    std::string why = upload_firmware_once(t, image, o);
    if (why.empty() && !firmware_running(t, std::max(1, o.run_probe_tries), o.timeout_ms)) {
      why = "upload echoed correctly but no status frame came back in run mode";
    }
    if (why.empty()) {
      report.loaded = true;
      report.log += "attempt " + std::to_string(k + 1) + ": loaded " + std::to_string(image.size()) + " bytes\n";
      return report;
    }
    report.log += "attempt " + std::to_string(k + 1) + ": " + why + "\n";
  }
  throw ResourceError("falcon " + t.describe() + ": firmware load failed after " + std::to_string(report.attempts) +
                      " attempts:\n" + report.log +
                      "what to try: unplug the Falcon's USB and power, plug them back in and retry; check that the "
                      "firmware file is the Novint Falcon firmware; make sure no other program holds the device");
}

}  // namespace hc::falcon
