/// `hapticloud devices` lists the Novint Falcons on the USB bus and their state;
/// `hapticloud falcon-check` opens one, guides the user through homing and runs a short
/// self-test (frame rate, position, a virtual floor through the servo loop). --emulate runs the
/// same check on the built-in emulator (no hardware).

#ifdef HC_HAVE_FALCON

#include "commands.hpp"

#include "hc/common/error.hpp"
#include "hc/falcon/emulator.hpp"
#include "hc/falcon/falcon_device.hpp"
#include "hc/falcon/firmware.hpp"
#include "hc/falcon/usb_transport.hpp"
#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/shared_state.hpp"

#include <CLI/CLI.hpp>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>

namespace hc::app {
namespace {

using namespace std::chrono_literals;

/// Firmware and homing state of an opened transport (no firmware is loaded here).
std::string probe_state(falcon::Transport& t) {
  if (!falcon::firmware_running(t, 3, 20)) return "boot loader (firmware not loaded)";
  const falcon::Frame idle = falcon::encode_command(falcon::CommandFrame{});
  falcon::FrameAssembler a;
  std::array<std::uint8_t, 64> buf{};
  for (int k = 0; k < 10; ++k) {
    if (t.write(idle, 20) != falcon::IoStatus::kOk) break;
    std::size_t n = 0;
    if (t.read(buf, n, 20) == falcon::IoStatus::kOk) a.push(std::span<const std::uint8_t>(buf.data(), n));
    falcon::Frame f{};
    falcon::StatusFrame s;
    if (a.take(f) && falcon::decode_status(f, s)) {
      return std::string("firmware running, ") + (s.homed_mask == falcon::kAllAxesHomed ? "homed" : "not homed");
    }
  }
  return "firmware running, no status frame";
}

void run_devices(bool probe) {
  const auto found = falcon::list_usb_falcons();
  if (found.empty()) {
    std::cout << "no Novint Falcon found (USB 0403:cb48); check the USB cable and the power supply\n";
    return;
  }
  for (const auto& f : found) {
    std::cout << "#" << f.index << "  bus " << f.bus << " address " << f.address << "  port " << f.port_path
              << "  serial " << (f.serial.empty() ? "?" : f.serial) << "  ";
    if (!f.accessible) {
      std::cout << f.problem << "\n";
      continue;
    }
    if (!probe) {
      std::cout << "accessible\n";
      continue;
    }
    try {
      auto t = falcon::UsbFalconProvider(f.index).open();
      std::cout << probe_state(*t) << "\n";
    } catch (const Error& e) {
      std::cout << e.what() << "\n";
    }
  }
}

struct CheckOptions {
  int index = 0;
  std::string firmware;
  bool emulate = false;
  double home_timeout_s = 60.0;
  double floor_s = 5.0;
};

/// @throws hc::ConfigError naming `option` unless `v` is finite and in (0, hi].
void check_seconds(const char* option, double v, double hi) {
  if (!std::isfinite(v) || !(v > 0.0) || v > hi) {
    std::ostringstream s;
    s << "falcon-check: " << option << " " << v << " is out of range (expected a number of seconds in (0, " << hi
      << "])";
    throw ConfigError(s.str());
  }
}

/// Checks every numeric option before anything is opened. @throws hc::ConfigError naming it.
void check_options(const CheckOptions& o) {
  if (o.index < 0) throw ConfigError("falcon-check: --index " + std::to_string(o.index) + " is out of range (expected >= 0)");
  check_seconds("--home-timeout", o.home_timeout_s, 3600.0);
  check_seconds("--floor-seconds", o.floor_s, 3600.0);
}

constexpr int kInterrupted = 2;  // run_falcon_check's result when SIGINT/SIGTERM cut it short

/// Opens, homes and arms a Falcon (or the emulator) over a virtual floor. @return 0 pass, 1 fail,
/// kInterrupted when SIGINT/SIGTERM ended it early. @throws hc::ResourceError when it cannot
/// open or home. Real-time: no (runs the servo loop on its own thread).
int run_falcon_check(const CheckOptions& o) {
  falcon::install_stop_signal_handlers();
  haptics::SteadyClock clock;
  falcon::FalconConfig cfg;
  cfg.firmware_path = o.firmware;
  std::shared_ptr<falcon::FalconEmulator> emu;
  std::unique_ptr<falcon::TransportProvider> provider;
  if (o.emulate) {
    falcon::EmulatorOptions eo;
    eo.firmware_preloaded = true;
    emu = std::make_shared<falcon::FalconEmulator>(eo);
    // The emulated hand: the homing gesture, then it rests 5 mm below the virtual floor.
    emu->set_hand(falcon::EmulatedHand{[frame = cfg.frame](double t) {
      const Eigen::Vector3d c = falcon::FalconKinematics::workspace_centre_m();
      if (t < 0.3) return Eigen::Vector3d(c + Eigen::Vector3d(0, 0, 0.04 * t / 0.3));
      if (t < 0.6) return Eigen::Vector3d(c + Eigen::Vector3d(0, 0, 0.04 * (0.6 - t) / 0.3));
      return frame.to_falcon(Eigen::Vector3d(0, 0, -0.005));
    }});
    provider = std::make_unique<falcon::EmulatorProvider>(emu);
  } else {
    provider = std::make_unique<falcon::UsbFalconProvider>(o.index);
  }
  falcon::FalconDevice dev(clock, std::move(provider), cfg);
  std::cout << "falcon-check: opening " << dev.info().name << "\n";
  dev.open();
  const auto& fw = dev.firmware_report();
  std::cout << "  firmware: " << (fw.already_running ? "already running" : "loaded (" + std::to_string(fw.attempts) + " attempt(s))")
            << "\n";

  // A virtual floor at device z = 0, 100 mm square; the servo loop runs on its own thread and
  // homes the device first (forces stay off until every arm is homed).
  HeightField floor(GridGeometry{11, 11, -0.05, -0.05, 0.01});
  for (int r = 0; r < 11; ++r)
    for (int c = 0; c < 11; ++c) floor.at(r, c) = 0.0F;
  haptics::SurfaceLayers layers;
  layers.depth = &floor;
  haptics::SharedState shared(std::make_unique<haptics::HapticSurface>(layers, haptics::SurfaceOptions{}));
  haptics::ServoConfig scfg;
  scfg.proxy.stiffness_n_per_m = 500.0;
  scfg.proxy.max_force_n = 4.0;
  haptics::ServoLoop loop(dev, shared, clock, scfg);
  const haptics::RealtimeReport rt = loop.start();
  if (!rt.detail.empty()) std::cout << "  realtime: " << rt.detail << "\n";
  std::cout << "  " << dev.homing_message() << "\n";
  const auto t0 = std::chrono::steady_clock::now();
  std::string last = dev.homing_message();
  while (!dev.homed() && !falcon::stop_requested()) {
    if (std::chrono::steady_clock::now() - t0 > std::chrono::duration<double>(o.home_timeout_s)) {
      loop.stop();
      throw ResourceError("falcon-check: not homed after " + std::to_string(o.home_timeout_s) + " s: " + dev.homing_message());
    }
    const std::string m = dev.homing_message();
    if (m != last) std::cout << "  " << m << "\n";
    last = m;
    std::this_thread::sleep_for(20ms);
  }
  if (!dev.homed()) {  // the loop ended on SIGINT/SIGTERM, not by homing
    loop.stop();
    dev.close();
    std::cout << "  interrupted (not homed)\nfalcon-check: INTERRUPTED before the self-test ran\n";
    return kInterrupted;
  }
  std::cout << "  homed\n";
  const std::uint64_t frames0 = dev.status().frames;
  shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
  std::cout << "  armed: a flat floor at mid height for " << o.floor_s << " s; press down on it\n";
  double max_force = 0.0;
  std::uint64_t contact = 0, samples = 0;
  const auto t1 = std::chrono::steady_clock::now();
  while (std::chrono::steady_clock::now() - t1 < std::chrono::duration<double>(o.floor_s) && !falcon::stop_requested()) {
    haptics::Snapshot s;
    shared.snapshots.read(s);
    max_force = std::max(max_force, s.device_force_n.eigen().norm());
    contact += s.in_contact ? 1 : 0;
    ++samples;
    haptics::ButtonEvent b;
    while (shared.button_events.try_pop(b)) std::cout << "  buttons " << b.buttons << " (pressed " << b.pressed << ")\n";
    std::this_thread::sleep_for(10ms);
  }
  dev.disarm();  // forces off before the loop stops (the watchdog only guards an armed device)
  loop.stop();
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  const falcon::FalconStatus st = dev.status();
  const double rate = static_cast<double>(st.frames - frames0) / secs;
  dev.close();
  std::printf("  frames %.0f /s, stale reads %llu, bad frames %llu, watchdog trips %llu, io errors %llu\n", rate,
              static_cast<unsigned long long>(st.stale_reads), static_cast<unsigned long long>(st.bad_frames),
              static_cast<unsigned long long>(st.watchdog_trips), static_cast<unsigned long long>(st.io_errors));
  std::printf("  in contact %.0f%% of the samples, max force %.2f N, servo overruns %llu\n",
              samples ? 100.0 * static_cast<double>(contact) / static_cast<double>(samples) : 0.0, max_force,
              static_cast<unsigned long long>(loop.stats().overruns));
  if (falcon::stop_requested()) {
    std::cout << "falcon-check: INTERRUPTED during the floor test (no verdict)\n";
    return kInterrupted;
  }
  const bool ok = rate > 500.0 && st.io_errors == 0 && st.watchdog_trips == 0;
  std::cout << "falcon-check: " << (ok ? "PASS" : "FAIL (frame rate below 500/s or I/O errors; see above)") << "\n";
  return ok ? 0 : 1;
}

}  // namespace

void add_falcon_command(CLI::App& app) {
  auto probe = std::make_shared<bool>(true);
  CLI::App* dev = app.add_subcommand("devices", "List connected Novint Falcons and their state");
  dev->add_flag("!--no-probe", *probe, "Do not open the devices (only list them)");
  dev->callback([probe] { run_devices(*probe); });

  auto o = std::make_shared<CheckOptions>();
  CLI::App* chk = app.add_subcommand("falcon-check", "Home a Novint Falcon and run a short self-test");
  chk->add_option("--index", o->index, "Which Falcon (see `hapticloud devices`)")->capture_default_str();
  chk->add_option("--firmware", o->firmware,
                  std::string("Firmware image if the firmware is not running (default: $") + falcon::kFirmwareEnvVar + ")");
  chk->add_flag("--emulate", o->emulate, "Check the built-in emulator instead of hardware");
  chk->add_option("--home-timeout", o->home_timeout_s, "Seconds to wait for homing, (0, 3600]")->capture_default_str();
  chk->add_option("--floor-seconds", o->floor_s, "Seconds of the virtual-floor test, (0, 3600]")->capture_default_str();
  chk->callback([o] {
    check_options(*o);
    const int rc = run_falcon_check(*o);
    if (rc == kInterrupted) throw ResourceError("falcon-check interrupted (SIGINT/SIGTERM) before it finished");
    if (rc != 0) throw ResourceError("falcon-check failed");
  });
}

}  // namespace hc::app

#endif  // HC_HAVE_FALCON
