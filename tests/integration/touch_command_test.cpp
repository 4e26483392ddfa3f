// End-to-end: `hapticloud touch` on a run config (scene built first) and the paper's validation.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "app_runner.hpp"
#include "test_paths.hpp"

#include "float_tiff.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using hc::test::is_png;
using hc::test::read_json;
using hc::test::run_app;

/// One row of trace.csv (grid frame, SI units), the columns this test reads.
struct TraceRow {
  double hip[3], proxy[3], force[3];
  bool contact;
};

std::vector<TraceRow> read_trace(const fs::path& file) {
  std::ifstream in(file);
  std::string line;
  std::getline(in, line);
  std::vector<std::string> names;
  {
    std::stringstream ss(line);
    for (std::string n; std::getline(ss, n, ',');) names.push_back(n);
  }
  const auto col = [&](const std::string& n) {
    const auto it = std::find(names.begin(), names.end(), n);
    EXPECT_NE(it, names.end()) << "no column " << n << " in " << file;
    return static_cast<std::size_t>(it - names.begin());
  };
  const std::size_t hip = col("hip_x_m"), proxy = col("proxy_x_m"), force = col("force_x_n"), contact = col("contact");
  std::vector<TraceRow> rows;
  while (std::getline(in, line)) {
    std::vector<double> v;
    std::stringstream ss(line);
    for (std::string f; std::getline(ss, f, ',');) v.push_back(std::stod(f));
    if (v.size() != names.size()) break;
    TraceRow r{};
    for (std::size_t k = 0; k < 3; ++k) {
      r.hip[k] = v[hip + k];
      r.proxy[k] = v[proxy + k];
      r.force[k] = v[force + k];
    }
    r.contact = v[contact] != 0.0;
    rows.push_back(r);
  }
  return rows;
}

/// A 32-bit float layer of the scene, read with libtiff (independently of the program's
/// OpenCV-based reader), placed on the grid of scene.yaml (node-centred, row 0 = smallest y).
struct Layer {
  int rows = 0, cols = 0;
  double x0 = 0, y0 = 0, cell = 0;
  std::vector<float> v;
  /// Bilinear interpolation at (x, y) [m], grid frame; clamped to the border.
  double at(double x, double y) const {
    const double u = std::clamp((x - x0) / cell, 0.0, cols - 1.000001), w = std::clamp((y - y0) / cell, 0.0, rows - 1.000001);
    const int c = static_cast<int>(u), r = static_cast<int>(w);
    const double a = u - c, b = w - r;
    const auto z = [&](int rr, int cc) { return static_cast<double>(v[static_cast<std::size_t>(rr * cols + cc)]); };
    return (1 - a) * (1 - b) * z(r, c) + a * (1 - b) * z(r, c + 1) + (1 - a) * b * z(r + 1, c) + a * b * z(r + 1, c + 1);
  }
};

using hc::test::yaml_number;

Layer read_layer(const fs::path& scene, const std::string& name) {
  Layer l;
  l.x0 = yaml_number(scene / "scene.yaml", "x0_m");
  l.y0 = yaml_number(scene / "scene.yaml", "y0_m");
  l.cell = yaml_number(scene / "scene.yaml", "cell_size_m");
  hc::test::FloatTiff t = hc::test::read_float_tiff(scene / (name + ".tiff"));
  l.rows = t.rows;
  l.cols = t.cols;
  l.v = std::move(t.v);
  return l;
}

double rms(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0.0 : std::sqrt(s / static_cast<double>(v.size()));
}

TEST(TouchCommand, ValidationOnTheSinusoidConfigWritesBothSessionsPlotsAndReport) {
  const fs::path out = hc::test::temp_dir("validate") / "touch";
  std::string log;
  const std::string cfg = (fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml").string();
  ASSERT_EQ(run_app("touch " + cfg + " --validate --seconds 3 --out " + out.string(), &log), 0) << log;
  EXPECT_TRUE(fs::exists(out / "pipeline" / "scene" / "scene.yaml"));
  EXPECT_TRUE(is_png(out / "validation_proxy_z.png"));
  EXPECT_TRUE(is_png(out / "validation_force.png"));
  EXPECT_TRUE(fs::exists(out / "report.md"));
  const json with = read_json(out / "with_texture_friction" / "summary.json");
  const json without = read_json(out / "without_texture_friction" / "summary.json");
  for (const json* s : {&with, &without}) {
    EXPECT_EQ((*s)["ticks"].get<long>(), 3000);
    EXPECT_GT((*s)["max_force_n"].get<double>(), 0.1);   // the hand pressed into the surface
    EXPECT_LE((*s)["max_force_n"].get<double>(), 8.0);   // never above the cap
    EXPECT_LE((*s)["deepest_proxy_below_surface_m"].get<double>(), 1e-6);
    EXPECT_GT((*s)["events"]["onset"].get<long>(), 0);
  }
  EXPECT_EQ(with["texture_gain"].get<double>(), 1.0);
  EXPECT_EQ(without["texture_gain"].get<double>(), 0.0);
  EXPECT_TRUE(with["friction"].get<bool>());
  EXPECT_FALSE(without["friction"].get<bool>());

  // The effects, from the traces (issue 15): 3 s = one press-slide cycle of the scripted hand
  // (press, slide 60 mm along +x, lift, fly back), one contact episode per session.
  const auto trace_with = read_trace(out / "with_texture_friction" / "trace.csv");
  const auto trace_without = read_trace(out / "without_texture_friction" / "trace.csv");
  ASSERT_EQ(trace_with.size(), 3000u);
  ASSERT_EQ(trace_without.size(), 3000u);

  // Texture. The renderer's surface is z = E + g·T (envelope, texture layers; g = 1 with, 0
  // without), and a proxy in contact rests on it. So, with the layers read from the scene and
  // interpolated here: with texture the proxy's height above the envelope is the texture under
  // it, without texture it is zero — the texture moved the proxy by T.
  const fs::path scene = out / "pipeline" / "scene";
  const Layer envelope = read_layer(scene, "envelope");
  const Layer texture = read_layer(scene, "texture");
  ASSERT_GT(envelope.rows, 1);
  ASSERT_EQ(texture.v.size(), envelope.v.size());
  const auto above_envelope = [&](const std::vector<TraceRow>& trace, std::vector<double>& t_under) {
    std::vector<double> d;
    for (const TraceRow& r : trace) {
      if (!r.contact) continue;
      d.push_back(r.proxy[2] - envelope.at(r.proxy[0], r.proxy[1]));
      t_under.push_back(texture.at(r.proxy[0], r.proxy[1]));
    }
    return d;
  };
  std::vector<double> t_with, t_without;
  const std::vector<double> d_with = above_envelope(trace_with, t_with);
  const std::vector<double> d_without = above_envelope(trace_without, t_without);
  ASSERT_GT(d_with.size(), 500u);  // the slide alone is 1.2 s
  ASSERT_GT(d_without.size(), 500u);
  // The texture under the path is real: the bilateral envelope (σ = 3 cells = 1.5 mm) flattens the
  // 5 mm, 40 mm-wavelength sinusoid by a few per cent, i.e. by 0.1 mm or more where the path
  // crosses it, and the 20 µm scan noise stays in T. A floor of 10 µm RMS is well below both.
  const double texture_rms = rms(t_with);
  EXPECT_GT(texture_rms, 10e-6);
  std::vector<double> err_with(d_with.size());
  for (std::size_t i = 0; i < d_with.size(); ++i) err_with[i] = d_with[i] - t_with[i];
  // On its surface within a tenth of the texture: with texture the proxy follows E + T ...
  EXPECT_LT(rms(err_with), 0.1 * texture_rms) << "with texture the proxy is not on envelope + texture";
  EXPECT_GT(rms(d_with), 0.9 * texture_rms);
  // ... without, it follows E, although the texture under its path is as large.
  EXPECT_LT(rms(d_without), 0.1 * rms(t_without)) << "without texture the proxy is not on the envelope";
  ::testing::Test::RecordProperty("texture_rms_m", std::to_string(texture_rms));
  ::testing::Test::RecordProperty("off_surface_rms_with_m", std::to_string(rms(err_with)));
  ::testing::Test::RecordProperty("above_envelope_rms_without_m", std::to_string(rms(d_without)));

  // Friction. The work the force does on the hand over a contact episode, W = Σ F·ΔX_hip. A
  // frictionless proxy sits at the closest point of the surface, so F = −∇U with
  // U(depth) = ∫ k·depth (capped): W = U(start) − U(end) = 0 for an episode from touch-down to
  // release; friction makes the force oppose the sliding and W = −Σ μ F_n |ΔX| < 0. Relative to
  // M = Σ |F| |ΔX|, −W/M is about μ/√(1+μ²) while sliding; the scene's μ_d ≥ mu_min = 0.05
  // (configs/sinusoid.yaml), so with friction −W/M must exceed half of that, and without it must
  // stay below a tenth of it.
  const auto work_ratio = [](const std::vector<TraceRow>& trace) {
    double w = 0, m = 0;
    for (std::size_t i = 0; i + 1 < trace.size(); ++i) {
      if (!trace[i].contact) continue;
      double f2 = 0, d2 = 0;
      for (int k = 0; k < 3; ++k) {
        const double dx = trace[i + 1].hip[k] - trace[i].hip[k];
        w += trace[i].force[k] * dx;
        f2 += trace[i].force[k] * trace[i].force[k];
        d2 += dx * dx;
      }
      m += std::sqrt(f2 * d2);
    }
    EXPECT_GT(m, 0.0);
    return m > 0 ? w / m : 0.0;
  };
  const double mu_min = 0.05;
  const double r_with = work_ratio(trace_with), r_without = work_ratio(trace_without);
  EXPECT_LT(r_with, -0.5 * mu_min) << "friction dissipated too little: W/M = " << r_with;
  EXPECT_LT(std::abs(r_without), 0.1 * mu_min) << "frictionless contact dissipated: W/M = " << r_without;
  ::testing::Test::RecordProperty("work_ratio_with", std::to_string(r_with));
  ::testing::Test::RecordProperty("work_ratio_without", std::to_string(r_without));
}

TEST(TouchCommand, RasterOnARunSceneWritesTraceAndPlots) {
  const fs::path dir = hc::test::temp_dir("raster");
  std::string log;
  const std::string cfg = (fs::path(HC_SOURCE_DIR) / "configs" / "bunny.yaml").string();
  ASSERT_EQ(run_app("run " + cfg + " --quiet --out " + (dir / "run").string(), &log), 0) << log;
  ASSERT_EQ(run_app("touch " + (dir / "run" / "scene").string() + " --path raster --seconds 4 --out " +
                        (dir / "touch").string(), &log), 0) << log;
  const json s = read_json(dir / "touch" / "summary.json");
  EXPECT_EQ(s["ticks"].get<long>(), 4000);
  // Overruns (ticks whose compute exceeded the period) depend on the machine's load in this
  // as-fast-as-possible run, so they are reported, not asserted.
  EXPECT_TRUE(s.contains("overruns"));
  EXPECT_LE(s["max_force_n"].get<double>(), 8.0);
  EXPECT_LE(s["deepest_proxy_below_surface_m"].get<double>(), 1e-6);
  EXPECT_GT(s["contact_fraction"].get<double>(), 0.05);
  EXPECT_TRUE(is_png(dir / "touch" / "proxy_z.png"));
  EXPECT_TRUE(is_png(dir / "touch" / "force.png"));
  std::ifstream trace(dir / "touch" / "trace.csv");
  std::string header;
  std::getline(trace, header);
  EXPECT_EQ(header.rfind("t_s,hip_x_m,hip_y_m,hip_z_m,proxy_x_m", 0), 0u) << header;
}

/// The rows of a --record file as numbers (parsed here, not by the program's reader): tick,
/// time_ns, x, y, z, buttons, fx, fy, fz.
std::vector<std::array<double, 9>> read_recording_rows(const fs::path& file, std::vector<std::string>* events = nullptr) {
  std::ifstream in(file);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "# hapticloud recording 2") << file;
  std::vector<std::array<double, 9>> rows;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '@') {
      if (events != nullptr) events->push_back(line);
      continue;
    }
    if (line.empty() || line[0] == '#' || line[0] == 't') continue;
    std::array<double, 9> r{};
    std::stringstream ss(line);
    std::string f;
    for (std::size_t k = 0; k < 9 && std::getline(ss, f, ','); ++k) r[k] = std::stod(f);
    rows.push_back(r);
  }
  return rows;
}

// The proof of a recording: a scripted session recorded, then replayed through the same
// servo path from the recording (recording again), renders every tick's force to 1e-9 N.
TEST(TouchCommand, AReplayOfARecordedSessionRendersTheSameForces) {
  const fs::path dir = hc::test::temp_dir("record_replay");
  std::string log;
  const std::string common = "touch --synthetic sinusoid --cells 200 --seconds 3 ";
  ASSERT_EQ(run_app(common + "--path raster --out " + (dir / "a").string() + " --record " + (dir / "a.csv").string(), &log),
            0) << log;
  // The replay is told another path: only the recording can give it the raster's positions.
  ASSERT_EQ(run_app(common + "--path circle --out " + (dir / "b").string() + " --device replay:" + (dir / "a.csv").string() +
                        " --record " + (dir / "b.csv").string(), &log), 0) << log;
  const auto a = read_recording_rows(dir / "a.csv");
  const auto b = read_recording_rows(dir / "b.csv");
  ASSERT_EQ(a.size(), 3000u);
  ASSERT_EQ(b.size(), a.size());
  double max_force = 0.0, max_diff = 0.0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    ASSERT_EQ(a[k][0], static_cast<double>(k));
    for (std::size_t c = 2; c < 5; ++c) ASSERT_EQ(a[k][c], b[k][c]) << "tick " << k;  // the same positions
    for (std::size_t c = 6; c < 9; ++c) {
      max_diff = std::max(max_diff, std::abs(a[k][c] - b[k][c]));
      max_force = std::max(max_force, std::abs(a[k][c]));
    }
  }
  EXPECT_GT(max_force, 0.5);  // the session touched the surface: the comparison is not of zeros
  EXPECT_LE(max_diff, 1e-9);
  // The replayed session's trace (written by the session, not the recorder) agrees too.
  const auto ta = read_trace(dir / "a" / "trace.csv");
  const auto tb = read_trace(dir / "b" / "trace.csv");
  ASSERT_EQ(ta.size(), tb.size());
  for (std::size_t k = 0; k < ta.size(); ++k)
    for (int c = 0; c < 3; ++c) ASSERT_NEAR(ta[k].force[c], tb[k].force[c], 1e-9) << "tick " << k;
  // An existing --record file is refused before anything runs, and left as it was.
  const auto size = fs::file_size(dir / "a.csv");
  EXPECT_EQ(run_app(common + "--out " + (dir / "c").string() + " --record " + (dir / "a.csv").string(), &log), 1);
  EXPECT_NE(log.find("exists already"), std::string::npos) << log;
  EXPECT_EQ(fs::file_size(dir / "a.csv"), size);
  EXPECT_FALSE(fs::exists(dir / "c"));
  log.clear();
  EXPECT_EQ(run_app(common + "--out " + (dir / "d").string() + " --device replay:" + (dir / "missing.csv").string(), &log), 1);
  EXPECT_NE(log.find("missing.csv"), std::string::npos) << log;
}

// Version 2 records what the servo applied and adopted with the tick: the session's arm at
// tick 0, and each scripted level switch at the tick its time falls on (T · rate, the simulated
// clock), with the servo rate in the header.
TEST(TouchCommand, ARecordingHoldsTheCommandsAndSurfaceSwitchesWithTheirTicks) {
  const fs::path dir = hc::test::temp_dir("record_events");
  std::string log;
  ASSERT_EQ(run_app("touch --synthetic sinusoid --cells 401 --path circle --seconds 3 --rate 500 --level 2 "
                    "--window-cells 100 --zoom-path '1:in,2:out' --out " + (dir / "a").string() + " --record " +
                        (dir / "a.csv").string(), &log), 0) << log;
  std::vector<std::string> events;
  const auto rows = read_recording_rows(dir / "a.csv", &events);
  ASSERT_EQ(rows.size(), 1500u);
  std::ifstream in(dir / "a.csv");
  std::string first, header;
  std::getline(in, first);
  std::getline(in, header);
  EXPECT_NE(header.find("; servo_rate_hz: 500"), std::string::npos) << header;
  std::vector<std::string> commands, surfaces;
  for (const std::string& e : events) (e.rfind("@surface,", 0) == 0 ? surfaces : commands).push_back(e);
  ASSERT_FALSE(commands.empty());
  EXPECT_EQ(commands.front().rfind("@command,0,arm,", 0), 0u) << commands.front();
  // The first window at tick 0, then two switches: 1 s and 2 s at 500 Hz are ticks 500 and
  // 1000; three different tags.
  ASSERT_EQ(surfaces.size(), 3u) << log;
  EXPECT_EQ(surfaces[0].rfind("@surface,0,", 0), 0u) << surfaces[0];
  EXPECT_EQ(surfaces[1].rfind("@surface,500,", 0), 0u) << surfaces[1];
  EXPECT_EQ(surfaces[2].rfind("@surface,1000,", 0), 0u) << surfaces[2];
  const auto tag = [](const std::string& e) { return e.substr(e.rfind(',') + 1); };
  EXPECT_NE(tag(surfaces[0]), tag(surfaces[1]));
  EXPECT_NE(tag(surfaces[1]), tag(surfaces[2]));
}

TEST(TouchCommand, NotASceneIsAOneLineError) {
  const fs::path dir = hc::test::temp_dir("bad");
  std::string log;
  EXPECT_EQ(run_app("touch " + dir.string() + " --out " + (dir / "o").string(), &log), 1);
  EXPECT_NE(log.find("neither a scene folder"), std::string::npos) << log;
}

}  // namespace
