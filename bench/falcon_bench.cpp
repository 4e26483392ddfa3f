// Falcon driver costs per servo tick: forward kinematics (warm-started Newton) and its accuracy,
// inverse kinematics, force → motor commands, frame encode/decode, and a whole device tick
// through the emulator.
#include "hc/falcon/emulator.hpp"
#include "hc/falcon/falcon_device.hpp"
#include "hc/falcon/kinematics.hpp"
#include "hc/falcon/protocol.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <numbers>
#include <vector>

namespace {

using Eigen::Vector3d;
using hc::falcon::FalconKinematics;

/// 1 kHz samples of a fast Lissajous motion (peak speed ≈ 1 m/s) through the workspace.
struct Track {
  std::vector<Vector3d> x, theta;
  Track() {
    const FalconKinematics kin;
    const Vector3d c = FalconKinematics::workspace_centre_m();
    for (int k = 0; k < 4096; ++k) {
      const double t = k * 1e-3;
      const Vector3d p = c + Vector3d(0.04 * std::sin(2 * std::numbers::pi * 1.3 * t),
                                      0.035 * std::sin(2 * std::numbers::pi * 2.1 * t + 1),
                                      0.04 * std::sin(2 * std::numbers::pi * 3.7 * t + 2));
      Vector3d th;
      kin.inverse(p, th);
      x.push_back(p);
      theta.push_back(th);
    }
  }
};
const Track& track() {
  static const Track t;
  return t;
}

void BM_FkNewtonWarmStart(benchmark::State& state) {
  const FalconKinematics kin;
  const Track& tr = track();
  Vector3d x = tr.x[0];
  std::size_t k = 0;
  double iters = 0, worst = 0;
  std::int64_t n = 0;
  for (auto _ : state) {
    const auto r = kin.forward(tr.theta[k], x, 3);
    benchmark::DoNotOptimize(x);
    iters += r.iterations;
    worst = std::max(worst, (x - tr.x[k]).norm());
    ++n;
    if (++k == tr.x.size()) {
      k = 0;
      x = tr.x[0];
    }
  }
  state.counters["iterations"] = iters / static_cast<double>(n);
  state.counters["max_error_um"] = worst * 1e6;
}
BENCHMARK(BM_FkNewtonWarmStart);

void BM_FkNewtonCold(benchmark::State& state) {
  const FalconKinematics kin;
  const Track& tr = track();
  std::size_t k = 0;
  double iters = 0;
  std::int64_t n = 0;
  for (auto _ : state) {
    Vector3d x = FalconKinematics::workspace_centre_m();
    const auto r = kin.forward(tr.theta[k], x, 30, 1e-9);
    benchmark::DoNotOptimize(x);
    iters += r.iterations;
    ++n;
    k = (k + 97) % tr.x.size();
  }
  state.counters["iterations"] = iters / static_cast<double>(n);
}
BENCHMARK(BM_FkNewtonCold);

void BM_Inverse(benchmark::State& state) {
  const FalconKinematics kin;
  const Track& tr = track();
  std::size_t k = 0;
  Vector3d th;
  for (auto _ : state) {
    benchmark::DoNotOptimize(kin.inverse(tr.x[k], th));
    k = (k + 1) % tr.x.size();
  }
}
BENCHMARK(BM_Inverse);

void BM_CommandsForForce(benchmark::State& state) {
  const FalconKinematics kin;
  const Track& tr = track();
  std::size_t k = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(kin.commands_for_force(tr.x[k], tr.theta[k], Vector3d(1.0, -2.0, 3.0), 32000));
    k = (k + 1) % tr.x.size();
  }
}
BENCHMARK(BM_CommandsForForce);

void BM_EncodeCommand(benchmark::State& state) {
  hc::falcon::CommandFrame c{{1234, -2345, 345}, hc::falcon::kLedGreen, false};
  for (auto _ : state) {
    benchmark::DoNotOptimize(hc::falcon::encode_command(c));
    ++c.motor[0];
  }
}
BENCHMARK(BM_EncodeCommand);

void BM_DecodeStatus(benchmark::State& state) {
  const hc::falcon::Frame f = hc::falcon::encode_status(hc::falcon::StatusFrame{{100, -200, 300}, 1, 7});
  hc::falcon::StatusFrame s;
  for (auto _ : state) {
    benchmark::DoNotOptimize(hc::falcon::decode_status(f, s));
    benchmark::DoNotOptimize(s);
  }
}
BENCHMARK(BM_DecodeStatus);

void BM_AssemblerFrame(benchmark::State& state) {
  const hc::falcon::Frame f = hc::falcon::encode_status(hc::falcon::StatusFrame{{100, -200, 300}, 1, 7});
  hc::falcon::FrameAssembler a;
  hc::falcon::Frame out{};
  for (auto _ : state) {
    a.push(f);
    benchmark::DoNotOptimize(a.take(out));
  }
}
BENCHMARK(BM_AssemblerFrame);

/// read() + write() of a homed, armed FalconDevice on the emulator (includes the emulator's own
/// dynamics step and its mutex; the libusb transfer time is not in this number).
void BM_DeviceTickEmulated(benchmark::State& state) {
  hc::haptics::ManualClock clock;
  hc::falcon::EmulatorOptions eo;
  eo.firmware_preloaded = true;
  auto emu = std::make_shared<hc::falcon::FalconEmulator>(eo);
  hc::falcon::FalconConfig cfg;
  cfg.supervisor_thread = false;
  hc::falcon::FalconDevice dev(clock, std::make_unique<hc::falcon::EmulatorProvider>(emu), cfg);
  dev.open();
  const Vector3d c = FalconKinematics::workspace_centre_m();
  emu->set_hand(hc::falcon::EmulatedHand{[c](double t) {
    const double s = t < 0.3 ? t / 0.3 : (t < 0.6 ? (0.6 - t) / 0.3 : 0.0);
    return Vector3d(c + Vector3d(0, 0, 0.04 * s));
  }});
  hc::haptics::DeviceReading r;
  for (int k = 0; k < 1500 && !dev.homed(); ++k) {
    dev.read(r);
    dev.write(Vector3d::Zero());
    clock.advance_ns(1000000);
  }
  dev.arm();
  for (auto _ : state) {
    dev.read(r);
    dev.write(Vector3d(0.0, 0.0, 1.0));
    clock.advance_ns(1000000);
  }
  state.counters["homed"] = dev.homed() ? 1 : 0;
}
BENCHMARK(BM_DeviceTickEmulated);

}  // namespace
BENCHMARK_MAIN();
