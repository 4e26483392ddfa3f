// The scripted touch session (hc::session::run_touch_session) against independent oracles:
// Hooke's law for a static press on a plane, the analytic sinusoid under a sliding proxy, the
// synthetic scene's samples, the option checks and the files the writer makes.

#include "hc/common/error.hpp"
#include "hc/session/touch_session.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <string>

namespace hc::session {
namespace {

namespace fs = std::filesystem;

/// A horizontal plane z = z0 over a 100 mm square, n × n samples (depth only).
Scene plane_scene(int n, double z0) {
  const double side = 0.1;
  Scene s;
  s.geometry = GridGeometry{n, n, -side / 2, -side / 2, side / (n - 1)};
  s.layers.depth = HeightField(s.geometry);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) s.layers.depth.at(r, c) = static_cast<float>(z0);
  return s;
}

/// The paper's validation envelope, written here from Sec. 5.1: 4 mm · sin(2πx/40 mm) · sin(2πy/40 mm).
double envelope(double x, double y) {
  const double k = 2.0 * std::numbers::pi / 0.04;
  return 0.004 * std::sin(k * x) * std::sin(k * y);
}
double texture(double x, double y) {
  const double k = 2.0 * std::numbers::pi / 0.002;
  return 0.0002 * std::sin(k * x) * std::sin(k * y);
}

TEST(TouchSession, StaticPressOnAPlaneFollowsHookesLaw) {
  // The device sits exactly on the target (no hand): after the approach it holds 4 mm (device
  // frame) below the plane, so F = k · 4 mm upwards, and the proxy rests on the plane.
  const double z0 = 0.002, press = 0.004, k = 800.0;
  TouchSessionOptions o;
  o.path = "hold";
  o.hand = false;
  o.seconds = 2.0;
  o.friction = false;
  o.texture_gain = 0.0;
  o.stiffness_n_per_m = k;
  o.press_m = press;
  const TouchSessionResult r = run_touch_session(plane_scene(101, z0), o);
  ASSERT_EQ(r.trace.size(), 2000U);
  EXPECT_EQ(r.stats.ticks, 2000U);
  ASSERT_GT(r.map.scale, 0.0);
  // The last second: settled (approach 0.2 s, force ramp 0.25 s).
  for (std::size_t i = 1000; i < r.trace.size(); ++i) {
    const haptics::TickRecord& t = r.trace[i];
    ASSERT_TRUE(t.in_contact) << i;
    EXPECT_NEAR(t.proxy_m.z, z0, 1e-6) << i;
    // The HIP is press · scale (grid metres per device metre) below the plane.
    EXPECT_NEAR(z0 - t.hip_m.z, press * r.map.scale, 1e-6) << i;
    EXPECT_NEAR(t.force_n.z, k * press, 1e-3 * k * press) << i;
    EXPECT_NEAR(std::hypot(t.force_n.x, t.force_n.y), 0.0, 1e-6) << i;
    if (::testing::Test::HasFailure()) break;
  }
  EXPECT_NEAR(r.figures.max_force_n, k * press, 1e-3 * k * press);
  EXPECT_LE(r.figures.deepest_m, 1e-9);
  EXPECT_EQ(r.figures.events_by_type[0], 1U);  // one onset, no release
  EXPECT_EQ(r.figures.events_by_type[2], 0U);
}

TEST(TouchSession, TheForceIsCappedAtMaxForce) {
  // 20 mm into the plane at 800 N/m would be 16 N: the cap (3 N) holds.
  TouchSessionOptions o;
  o.path = "hold";
  o.hand = false;
  o.seconds = 1.5;
  o.press_m = 0.02;
  o.max_force_n = 3.0;
  const TouchSessionResult r = run_touch_session(plane_scene(51, 0.0), o);
  EXPECT_NEAR(r.figures.max_force_n, 3.0, 1e-9);
  EXPECT_NEAR(r.trace.back().force_n.eigen().norm(), 3.0, 1e-9);
}

TEST(TouchSession, SyntheticSinusoidSamplesTheAnalyticLayers) {
  const Scene s = synthetic_sinusoid_scene(101);
  ASSERT_EQ(s.layers.depth.rows(), 101);
  EXPECT_EQ(s.layers.mu_d.rows(), 0);
  const GridGeometry& g = s.geometry;
  EXPECT_NEAR(g.x0_m, -0.05, 1e-15);
  EXPECT_NEAR(g.cell_size_m, 0.001, 1e-15);
  for (int r = 0; r < 101; r += 7) {
    for (int c = 0; c < 101; c += 5) {
      const double x = -0.05 + 0.001 * c, y = -0.05 + 0.001 * r;
      EXPECT_NEAR(s.layers.envelope.at(r, c), envelope(x, y), 1e-8);
      EXPECT_NEAR(s.layers.texture.at(r, c), texture(x, y), 1e-8);
      EXPECT_NEAR(s.layers.depth.at(r, c), envelope(x, y) + texture(x, y), 1e-8);
    }
  }
  EXPECT_THROW(synthetic_sinusoid_scene(1), ConfigError);
}

TEST(TouchSession, ASlidingProxyStaysOnTheAnalyticSurface) {
  // Envelope only (texture gain 0), 0.25 mm samples: bilinear interpolation of the sinusoid is
  // within ~2 µm of it, so every tick in contact has its proxy on the analytic surface.
  TouchSessionOptions o;
  o.path = "circle";
  o.seconds = 3.0;
  o.texture_gain = 0.0;
  const TouchSessionResult r = run_touch_session(synthetic_sinusoid_scene(401), o);
  ASSERT_EQ(r.trace.size(), 3000U);
  std::size_t contact = 0;
  double force_sum = 0.0;
  for (std::size_t i = 0; i < r.trace.size(); ++i) {
    const haptics::TickRecord& t = r.trace[i];
    EXPECT_LE(t.force_n.eigen().norm(), o.max_force_n + 1e-9) << i;
    if (!t.in_contact) continue;
    ++contact;
    force_sum += t.force_n.eigen().norm();
    EXPECT_NEAR(t.proxy_m.z, envelope(t.proxy_m.x, t.proxy_m.y), 1e-5) << i;
    EXPECT_NEAR(r.surface_z_m[i], envelope(t.proxy_m.x, t.proxy_m.y), 1e-5) << i;
    if (::testing::Test::HasFailure()) break;
  }
  EXPECT_GT(contact, 1500U);  // the hand presses 10 mm below mid height, the relief is ±4 mm
  EXPECT_EQ(r.figures.contact_ticks, contact);
  EXPECT_NEAR(r.figures.mean_force_contact_n, force_sum / static_cast<double>(contact), 1e-9);
  EXPECT_LE(r.figures.deepest_m, 1e-6);
}

TEST(TouchSession, NumericOptionsAreRangeCheckedNamingTheOption) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const auto expect_rejected = [](TouchSessionOptions o, const std::string& what) {
    try {
      o.validate();
      ADD_FAILURE() << "accepted: " << what;
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  TouchSessionOptions o;
  EXPECT_NO_THROW(o.validate());
  auto with = [&](auto field, double v) {
    TouchSessionOptions x;
    x.*field = v;
    return x;
  };
  expect_rejected(with(&TouchSessionOptions::rate_hz, -5), "--rate -5");
  expect_rejected(with(&TouchSessionOptions::rate_hz, 20000), "--rate 20000");
  expect_rejected(with(&TouchSessionOptions::seconds, nan), "--seconds nan");
  expect_rejected(with(&TouchSessionOptions::seconds, 0), "--seconds 0");
  expect_rejected(with(&TouchSessionOptions::texture_gain, -1), "--texture-gain -1");
  expect_rejected(with(&TouchSessionOptions::mu_d, -0.1), "--mu-d -0.1");
  expect_rejected(with(&TouchSessionOptions::mu_s, nan), "--mu-s nan");
  expect_rejected(with(&TouchSessionOptions::stiffness_n_per_m, 0), "--stiffness 0");
  expect_rejected(with(&TouchSessionOptions::max_force_n, std::numeric_limits<double>::infinity()), "--max-force inf");
  expect_rejected(with(&TouchSessionOptions::rho, 1.5), "--rho 1.5");
  expect_rejected(with(&TouchSessionOptions::press_m, nan), "--press nan");
  expect_rejected(with(&TouchSessionOptions::speed_m_per_s, 0), "--speed 0");
  TouchSessionOptions cells;
  cells.levels = true;
  cells.window_cells = 1;
  expect_rejected(cells, "--window-cells 1");
  TouchSessionOptions path;
  path.path = "zigzag";
  expect_rejected(path, "zigzag");
}

TEST(TouchSession, WriterMakesTraceEventsAndSummaryMatchingTheResult) {
  const fs::path dir = fs::path(HC_BINARY_DIR) / "test-output" / "TouchSession.Writer";
  fs::remove_all(dir);
  TouchSessionOptions o;
  o.path = "line";
  o.seconds = 1.0;
  const TouchSessionResult r = run_touch_session(synthetic_sinusoid_scene(101), o);
  write_touch_session(r, o, "sinusoid \xff test", dir, R"({"extra": {"n": 3}})");
  std::ifstream trace(dir / "trace.csv");
  std::size_t lines = 0;
  for (std::string line; std::getline(trace, line);) ++lines;
  EXPECT_EQ(lines, r.trace.size() + 1);
  std::ifstream events(dir / "events.csv");
  lines = 0;
  for (std::string line; std::getline(events, line);) ++lines;
  EXPECT_EQ(lines, r.events.size() + 1);
  const nlohmann::json s = nlohmann::json::parse(std::ifstream(dir / "summary.json"));
  EXPECT_EQ(s["ticks"].get<long>(), 1000);
  EXPECT_EQ(s["path"].get<std::string>(), "line");
  EXPECT_NEAR(s["max_force_n"].get<double>(), r.figures.max_force_n, 1e-9 * r.figures.max_force_n);  // 10 digits
  EXPECT_EQ(s["extra"]["n"].get<int>(), 3);
  EXPECT_EQ(s["input"].get<std::string>().rfind("sinusoid ", 0), 0U);  // the bad byte replaced, valid JSON
  EXPECT_TRUE(fs::exists(dir / "proxy_z.png"));
  EXPECT_TRUE(fs::exists(dir / "force.png"));
  EXPECT_THROW(write_touch_session(r, o, "x", dir / "again", "[1, 2]"), ConfigError);
}

}  // namespace
}  // namespace hc::session
