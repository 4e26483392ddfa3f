// End-to-end: the hapticloud program run on the raw bunny scan and on the paper's sinusoid.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <gnu/libc-version.h>

#include "app_runner.hpp"
#include "float_tiff.hpp"
#include "test_paths.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using hc::test::read_json;

struct Outcome {
  int status = -1;
  std::string output;  // stdout and stderr together
};

/// The program with `args`, after `env` (a shell prefix such as "env -u X Y=1 ", or "").
Outcome run_app_env(const std::string& env, const std::string& args) {
  Outcome o;
  o.status = hc::test::run_app(args, &o.output, env);
  return o;
}

Outcome run_app(const std::string& args) { return run_app_env("", args); }

std::string config(const char* name) { return (fs::path(HC_SOURCE_DIR) / "configs" / name).string(); }

TEST(RunCommand, VersionAndHelp) {
  const Outcome v = run_app("--version");
  EXPECT_EQ(v.status, 0);
  EXPECT_NE(v.output.find("hapticloud "), std::string::npos);
  const Outcome h = run_app("--help");
  EXPECT_EQ(h.status, 0);
  EXPECT_NE(h.output.find("run"), std::string::npos);
}

TEST(ExportCommand, WritesPlyAndStlOfARunsSceneAndRefusesToOverwrite) {
  const fs::path dir = hc::test::temp_dir("export_cmd");
  const fs::path out = dir / "run";
  ASSERT_EQ(run_app("run " + config("sinusoid.yaml") + " --out " + out.string() + " --quiet").status, 0);
  const Outcome ply = run_app("export " + (out / "scene").string() + " --format ply --out " + (dir / "s.ply").string());
  ASSERT_EQ(ply.status, 0) << ply.output;
  EXPECT_NE(ply.output.find("triangles"), std::string::npos) << ply.output;
  const Outcome stl = run_app("export " + (out / "scene").string() + " --format stl --out " + (dir / "s.stl").string());
  ASSERT_EQ(stl.status, 0) << stl.output;
  // The two formats agree: binary STL holds 84 bytes + 50 per triangle, and the PLY's header
  // names the same triangle count (the formats themselves are checked in mesh_export_test.cpp).
  std::ifstream in(dir / "s.ply", std::ios::binary);
  std::string line;
  long faces = -1;
  while (std::getline(in, line) && line != "end_header")
    if (line.rfind("element face ", 0) == 0) faces = std::stol(line.substr(13));
  ASSERT_GT(faces, 0);
  EXPECT_EQ(static_cast<long>(fs::file_size(dir / "s.stl")), 84 + 50 * faces);
  const auto before = fs::file_size(dir / "s.ply");
  const Outcome again = run_app("export " + (out / "scene").string() + " --out " + (dir / "s.ply").string());
  EXPECT_NE(again.status, 0);
  EXPECT_NE(again.output.find("exists already"), std::string::npos) << again.output;
  EXPECT_EQ(fs::file_size(dir / "s.ply"), before);
  // Level 1 halves the resolution: about a quarter of the triangles (the rim loses a little).
  const Outcome l1 = run_app("export " + (out / "scene").string() + " --level 1 --format stl --out " + (dir / "s1.stl").string());
  ASSERT_EQ(l1.status, 0) << l1.output;
  const double faces1 = (static_cast<double>(fs::file_size(dir / "s1.stl")) - 84.0) / 50.0;
  EXPECT_GT(faces1, 0.2 * static_cast<double>(faces));
  EXPECT_LT(faces1, 0.3 * static_cast<double>(faces));
  const Outcome deep = run_app("export " + (out / "scene").string() + " --level 29 --out " + (dir / "s29.ply").string());
  EXPECT_NE(deep.status, 0);
  EXPECT_NE(deep.output.find("export --level = 29: the scene has levels 0 to"), std::string::npos) << deep.output;
  EXPECT_FALSE(fs::exists(dir / "s29.ply"));
  const Outcome bad = run_app("export " + (out / "scene").string() + " --format gltf --out " + (dir / "s.gltf").string());
  EXPECT_NE(bad.status, 0);
  EXPECT_NE(bad.output.find("expected one of: ply, stl, obj, geotiff"), std::string::npos) << bad.output;
}

TEST(ExportCommand, GeoTiffIsTheScenesDepthUprightAndLayersLevelsAndWindowsAreChecked) {
  const fs::path dir = hc::test::temp_dir("export_geotiff");
  const fs::path out = dir / "run";
  ASSERT_EQ(run_app("run " + config("sinusoid.yaml") + " --out " + out.string() + " --quiet").status, 0);
  const Outcome o = run_app("export " + (out / "scene").string() + " --format geotiff --out " + (dir / "d.tif").string());
  ASSERT_EQ(o.status, 0) << o.output;
  EXPECT_NE(o.output.find("the scan's file frame"), std::string::npos) << o.output;  // sinusoid: a top view
  // Read with libtiff, beside the scene's own depth.tiff (row 0 = smallest y): the export is the
  // same grid upside down (row 0 = largest y), NaN where the scene has no data, and the file
  // frame differs from the grid frame by the recentring only (m, no rotation): one constant.
  const hc::test::FloatTiff scene = hc::test::read_float_tiff(out / "scene" / "depth.tiff");
  const hc::test::FloatTiff geo = hc::test::read_float_tiff(dir / "d.tif");
  ASSERT_EQ(geo.rows, scene.rows);
  ASSERT_EQ(geo.cols, scene.cols);
  double lo = 1e300, hi = -1e300;
  int valid = 0;
  for (int j = 0; j < geo.rows; ++j)
    for (int i = 0; i < geo.cols; ++i) {
      const float s = scene.at(geo.rows - 1 - j, i), g = geo.at(j, i);
      ASSERT_EQ(std::isnan(s), std::isnan(g)) << j << " " << i;
      if (std::isnan(s)) continue;
      lo = std::min(lo, static_cast<double>(g) - s);
      hi = std::max(hi, static_cast<double>(g) - s);
      ++valid;
    }
  ASSERT_GT(valid, geo.rows * geo.cols / 2);
  // The sinusoid is in metres with no view rotation: file z = grid z + the recentring's z.
  const fs::path yaml = out / "scene" / "scene.yaml";
  const double off_z = hc::test::yaml_number(yaml, "recentre_offset_m", 2);
  EXPECT_NEAR(lo, off_z, 1e-7);
  EXPECT_NEAR(hi, off_z, 1e-7);
  // Other layers: μ_d as stored; a layer the scene lacks, an unknown layer, and a level's
  // missing layer are errors naming it; a mesh format takes no --layer.
  const Outcome mu = run_app("export " + (out / "scene").string() + " --format geotiff --layer mu_d --out " + (dir / "mu.tif").string());
  ASSERT_EQ(mu.status, 0) << mu.output;
  const hc::test::FloatTiff mu_scene = hc::test::read_float_tiff(out / "scene" / "mu_d.tiff");
  const hc::test::FloatTiff mu_geo = hc::test::read_float_tiff(dir / "mu.tif");
  ASSERT_EQ(mu_geo.rows, mu_scene.rows);
  EXPECT_EQ(mu_geo.at(0, 3), mu_scene.at(mu_scene.rows - 1, 3));
  const Outcome l1 = run_app("export " + (out / "scene").string() + " --format geotiff --level 1 --out " + (dir / "d1.tif").string());
  ASSERT_EQ(l1.status, 0) << l1.output;
  EXPECT_EQ(hc::test::read_float_tiff(dir / "d1.tif").cols, (scene.cols + 1) / 2);
  const Outcome none = run_app("export " + (out / "scene").string() + " --format geotiff --layer intensity --out " + (dir / "i.tif").string());
  EXPECT_NE(none.status, 0);
  EXPECT_NE(none.output.find("export --layer = intensity: the scene has no such layer"), std::string::npos) << none.output;
  const Outcome unknown = run_app("export " + (out / "scene").string() + " --format geotiff --layer height --out " + (dir / "h.tif").string());
  EXPECT_NE(unknown.status, 0);
  EXPECT_NE(unknown.output.find("expected one of: depth, envelope"), std::string::npos) << unknown.output;
  const Outcome lvl = run_app("export " + (out / "scene").string() + " --format geotiff --level 1 --layer cell_error --out " + (dir / "e.tif").string());
  EXPECT_NE(lvl.status, 0);
  EXPECT_NE(lvl.output.find("levels above 0 hold depth"), std::string::npos) << lvl.output;
  // --window 0 0 1 1 (grid frame; the sinusoid is recentred on 0): the upper-right quadrant,
  // i.e. the top-right block of the full, upright image.
  const Outcome win = run_app("export " + (out / "scene").string() + " --format geotiff --window 0 0 1 1 --out " + (dir / "w.tif").string());
  ASSERT_EQ(win.status, 0) << win.output;
  const hc::test::FloatTiff w = hc::test::read_float_tiff(dir / "w.tif");
  ASSERT_GT(w.rows, geo.rows / 2 - 2);
  ASSERT_LT(w.rows, geo.rows / 2 + 2);
  ASSERT_GT(w.cols, geo.cols / 2 - 2);
  ASSERT_LT(w.cols, geo.cols / 2 + 2);
  for (int j = 0; j < w.rows; ++j)
    for (int i = 0; i < w.cols; ++i) {
      const float a = w.at(j, i), b = geo.at(j, geo.cols - w.cols + i);
      ASSERT_TRUE(a == b || (std::isnan(a) && std::isnan(b))) << j << " " << i;
    }
  const Outcome far = run_app("export " + (out / "scene").string() + " --format stl --window 5 5 6 6 --out " + (dir / "far.stl").string());
  EXPECT_NE(far.status, 0);
  EXPECT_NE(far.output.find("holds fewer than 2 x 2 nodes"), std::string::npos) << far.output;
  const Outcome mesh = run_app("export " + (out / "scene").string() + " --format ply --layer mu_d --out " + (dir / "m.ply").string());
  EXPECT_NE(mesh.status, 0);
  for (const char* f : {"i.tif", "h.tif", "e.tif", "m.ply", "far.stl"}) EXPECT_FALSE(fs::exists(dir / f)) << f;
}

TEST(ExportCommand, GeoTiffOfAScanInFeetIsInItsOwnFrameAndUnits) {
  // PDAL's simple.las (Autzen, feet, about 637 000 ft east): a top view, so the GeoTIFF is in
  // the file's frame: file = (grid + recentre offset) / 0.3048, for x, y and z alike. The
  // oracle reads scene.yaml and the scene's depth.tiff, the GeoTIFF's tags and pixels with libtiff.
  const fs::path dir = hc::test::temp_dir("export_geotiff_ft");
  const fs::path out = dir / "run";
  // The sample's verdict is warn (docs in the config), which exits 0.
  ASSERT_EQ(run_app("run " + config("las_sample.yaml") + " --out " + out.string() + " --quiet --set lod.report=false").status, 0);
  const Outcome o = run_app("export " + (out / "scene").string() + " --format geotiff --out " + (dir / "d.tif").string());
  ASSERT_EQ(o.status, 0) << o.output;
  const fs::path yaml = out / "scene" / "scene.yaml";
  const double ft = 0.3048;
  const double ox = hc::test::yaml_number(yaml, "recentre_offset_m", 0), oy = hc::test::yaml_number(yaml, "recentre_offset_m", 1),
               oz = hc::test::yaml_number(yaml, "recentre_offset_m", 2);
  ASSERT_GT(ox, 1e5);  // real map coordinates: an offset the export must put back
  const double x0 = hc::test::yaml_number(yaml, "x0_m"), y0 = hc::test::yaml_number(yaml, "y0_m"),
               cell = hc::test::yaml_number(yaml, "cell_size_m");
  const hc::test::FloatTiff scene = hc::test::read_float_tiff(out / "scene" / "depth.tiff");
  const hc::test::FloatTiff geo = hc::test::read_float_tiff(dir / "d.tif");
  ASSERT_EQ(geo.rows, scene.rows);
  ASSERT_EQ(geo.cols, scene.cols);
  // GeoTIFF 1.1 (OGC 19-008r4) sec. 7.2: ModelPixelScale (Sx, Sy, Sz) and a tiepoint (I, J, K,
  // X, Y, Z) tying the corner of pixel (0, 0) to the model (pixel-is-area).
  const std::vector<double> scale = hc::test::read_tiff_doubles(dir / "d.tif", 33550);
  const std::vector<double> tie = hc::test::read_tiff_doubles(dir / "d.tif", 33922);
  ASSERT_GE(scale.size(), 2u);
  ASSERT_GE(tie.size(), 6u);
  EXPECT_NEAR(scale[0], cell / ft, 1e-9);
  EXPECT_NEAR(scale[1], cell / ft, 1e-9);
  EXPECT_NEAR(tie[3], (x0 + ox) / ft - 0.5 * cell / ft, 1e-6);
  EXPECT_NEAR(tie[4], (y0 + (scene.rows - 1) * cell + oy) / ft + 0.5 * cell / ft, 1e-6);
  int valid = 0;
  for (int j = 0; j < geo.rows; ++j)
    for (int i = 0; i < geo.cols; ++i) {
      const float s = scene.at(geo.rows - 1 - j, i), g = geo.at(j, i);
      ASSERT_EQ(std::isnan(s), std::isnan(g)) << j << " " << i;
      if (std::isnan(s)) continue;
      EXPECT_NEAR(g, (s + oz) / ft, 1e-3) << j << " " << i;  // float32 of a few hundred feet
      ++valid;
    }
  EXPECT_GT(valid, 0);
}

// The environment `hapticloud run` ran in, as its report records it (report.json, process).
std::string tunables_of_run(const std::string& env, const fs::path& out) {
  const Outcome o = run_app_env(env, "run " + config("sinusoid.yaml") + " --out " + out.string() + " --quiet --set grid.n=64");
  EXPECT_EQ(o.status, 0) << o.output;
  if (o.status != 0) return "?";
  return read_json(out / "report.json")["process"]["glibc_tunables"].get<std::string>();
}

TEST(RunCommand, BatchRunsAskGlibcForHugePagesWhereTheKernelAndLibraryCanGiveThem) {
  // The oracle: what this machine offers, read here, not by the program. The tunable exists from
  // glibc 2.35; transparent huge pages in mode madvise are given only to memory advised for them.
  int major = 0, minor = 0;
  ASSERT_EQ(std::sscanf(gnu_get_libc_version(), "%d.%d", &major, &minor), 2);
  std::string mode;
  std::getline(std::ifstream("/sys/kernel/mm/transparent_hugepage/enabled"), mode);
  const bool acts = (major > 2 || (major == 2 && minor >= 35)) && mode.find("[madvise]") != std::string::npos;
  std::printf("glibc %d.%d, transparent_hugepage/enabled: '%s': the program %s\n", major, minor, mode.c_str(),
              acts ? "adds the tunable" : "leaves the environment as it is");
  const fs::path dir = hc::test::temp_dir("huge_pages");
  const std::string clean = "env -u GLIBC_TUNABLES -u HAPTICLOUD_HEAP_HUGE_PAGES -u HAPTICLOUD_HEAP_HUGE_PAGES_STARTED ";
  EXPECT_EQ(tunables_of_run(clean, dir / "default"), acts ? "glibc.malloc.hugetlb=1" : "");
  // The user's own tunables are kept, and a choice of theirs for this one is not overridden.
  EXPECT_EQ(tunables_of_run(clean + "GLIBC_TUNABLES=glibc.malloc.perturb=0 ", dir / "kept"),
            acts ? "glibc.malloc.perturb=0:glibc.malloc.hugetlb=1" : "glibc.malloc.perturb=0");
  EXPECT_EQ(tunables_of_run(clean + "GLIBC_TUNABLES=glibc.malloc.hugetlb=0 ", dir / "theirs"), "glibc.malloc.hugetlb=0");
  EXPECT_EQ(tunables_of_run(clean + "HAPTICLOUD_HEAP_HUGE_PAGES=off ", dir / "off"), "");
  // A process that says it was started again already (the loop guard) starts no more.
  EXPECT_EQ(tunables_of_run(clean + "HAPTICLOUD_HEAP_HUGE_PAGES_STARTED=1 ", dir / "started"), "");
}

TEST(RunCommand, SinusoidReportMatchesTheAnalyticSurface) {
  const fs::path out = hc::test::temp_dir("sinusoid") / "run";
  const Outcome o = run_app("run " + config("sinusoid.yaml") + " --out " + out.string());
  ASSERT_EQ(o.status, 0) << o.output;
  for (const char* f : {"report.md", "report.json", "scene/scene.yaml", "scene/depth.tiff", "scene/texture.tiff",
                        "scene/mu_d.tiff", "scene/mu_s.tiff", "previews/depth.png", "previews/hillshade.png",
                        "previews/cross_check_error.png"}) {
    EXPECT_TRUE(fs::exists(out / f)) << f;
  }
  const json r = read_json(out / "report.json");
  EXPECT_EQ(r["grid"]["cols"].get<int>(), 200);
  const double cell_mm = r["grid"]["cell_size_m"].get<double>() * 1000.0;
  EXPECT_NEAR(cell_mm, 100.0 / 199.0, 0.05);  // 10 cm over 200 samples
  // Dense samples with 20 µm noise: the grid must agree with its points far below a cell.
  const json& cc = r["cross_check"];
  EXPECT_LT(cc["point_vertical"]["rms_mm"].get<double>(), 0.25 * cell_mm);
  EXPECT_LT(cc["cell_to_point"]["p95_mm"].get<double>(), cell_mm);
  EXPECT_GT(cc["supported_fraction"].get<double>(), 0.95);
  EXPECT_EQ(r["friction_model"].get<std::string>(), "paper");
  bool saw_reproject = false;
  for (const auto& s : r["stages"]) {
    EXPECT_GE(s["seconds"].get<double>(), 0.0);
    if (s["stage"] == "reproject") {
      saw_reproject = true;
      EXPECT_GT(s["count_in"].get<long>(), 300000);
    }
  }
  EXPECT_TRUE(saw_reproject);
}

TEST(RunCommand, RawBunnyScanGivesAPlausibleGrid) {
  const fs::path out = hc::test::temp_dir("bunny") / "run";
  const Outcome o = run_app("run " + config("bunny.yaml") + " --out " + out.string() + " --quiet");
  ASSERT_EQ(o.status, 0) << o.output;
  const json r = read_json(out / "report.json");
  EXPECT_EQ(std::max(r["grid"]["rows"].get<int>(), r["grid"]["cols"].get<int>()), 300);
  // 40 256 points: the ingest stage reads them all.
  EXPECT_EQ(r["stages"][0]["count_out"].get<long>(), 40256);
  // The bunny is ~15 cm across: about 0.5 mm cells; the raw scan is dense, so the surface
  // follows its points to well under a cell and almost every cell is supported by a point.
  const double cell_mm = r["grid"]["cell_size_m"].get<double>() * 1000.0;
  EXPECT_GT(cell_mm, 0.4);
  EXPECT_LT(cell_mm, 0.6);
  EXPECT_LT(r["cross_check"]["point_vertical"]["p50_mm"].get<double>(), 0.25 * cell_mm);
  EXPECT_GT(r["cross_check"]["supported_fraction"].get<double>(), 0.9);
  EXPECT_GT(r["grid"]["valid_cells"].get<long>(), 20000);
  EXPECT_EQ(r["provenance"]["inputs"][0]["sha256"].get<std::string>(),
            "7d48f9fdf917311de680d074edce8aff25a4b9bfd87be9301822dace811209fb");
}

TEST(RunCommand, BadConfigFailsWithOneLineCauseAndWritesNothing) {
  const fs::path dir = hc::test::temp_dir("bad");
  std::ofstream(dir / "bad.yaml") << "input: {files: [x.ply]}\ngrid: {n: 1}\n";
  const Outcome o = run_app("run " + (dir / "bad.yaml").string() + " --out " + (dir / "out").string());
  EXPECT_EQ(o.status, 1);
  EXPECT_NE(o.output.find("bad.yaml:2: grid.n = 1"), std::string::npos) << o.output;
  EXPECT_FALSE(fs::exists(dir / "out"));

  std::ofstream(dir / "missing.yaml") << "input: {files: [no_such_scan.ply]}\n";
  const Outcome m = run_app("run " + (dir / "missing.yaml").string() + " --out " + (dir / "out").string());
  EXPECT_EQ(m.status, 1);
  EXPECT_NE(m.output.find("no_such_scan.ply"), std::string::npos) << m.output;
  EXPECT_FALSE(fs::exists(dir / "out"));
}

TEST(RunCommand, SetOverridesAConfigKey) {
  const fs::path out = hc::test::temp_dir("set") / "run";
  const Outcome o = run_app("run " + config("sinusoid.yaml") + " --out " + out.string() +
                            " --quiet --set grid.n=64 --set layers.friction.model=curvature");
  ASSERT_EQ(o.status, 0) << o.output;
  const json r = read_json(out / "report.json");
  EXPECT_EQ(r["grid"]["cols"].get<int>(), 64);
  EXPECT_EQ(r["friction_model"].get<std::string>(), "curvature");
}

TEST(RunCommand, AFailedVerdictExitsFourAndKeepsTheReport) {
  // The raw bunny scan with one point 1 km above its middle and the outlier stage off: the grid
  // gets a cell at +1 km that only that point supports. The run must end with exit code 4
  // (docs/cli.md), name the failing reasons on stderr, and still write the report (the user
  // reads why). Oracle: the planted point, not the program's figures.
  const fs::path dir = hc::test::temp_dir("verdict_fail");
  const fs::path scan = hc::test::scan_path("bunny/bun000.ply");
  std::vector<std::array<double, 3>> pts;
  {
    // bun000.ply is ASCII: a header, then "x y z ..." per vertex.
    std::ifstream in(scan);
    std::string line;
    long n = 0;
    while (std::getline(in, line)) {
      if (line.rfind("element vertex", 0) == 0) n = std::stol(line.substr(15));
      if (line == "end_header") break;
    }
    ASSERT_EQ(n, 40256);
    for (long i = 0; i < n && std::getline(in, line); ++i) {
      std::array<double, 3> p{};
      ASSERT_EQ(std::sscanf(line.c_str(), "%lf %lf %lf", &p[0], &p[1], &p[2]), 3) << line;
      pts.push_back(p);
    }
  }
  ASSERT_EQ(pts.size(), 40256u);
  std::array<double, 3> lo = pts[0], hi = pts[0];
  for (const auto& p : pts)
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
  // The scan point nearest the middle of the x-y extent, raised by 1 km.
  std::array<double, 3> top = pts[0];
  double best = 1e300;
  for (const auto& p : pts) {
    const double d = std::hypot(p[0] - 0.5 * (lo[0] + hi[0]), p[1] - 0.5 * (lo[1] + hi[1]));
    if (d < best) best = d, top = p;
  }
  top[2] += 1000.0;
  const fs::path xyz = dir / "bunny_spike.xyz";
  {
    std::ofstream out(xyz);
    out.precision(17);
    for (const auto& p : pts) out << p[0] << ' ' << p[1] << ' ' << p[2] << '\n';
    out << top[0] << ' ' << top[1] << ' ' << top[2] << '\n';
  }
  const fs::path out = dir / "run";
  const Outcome o = run_app("run " + config("bunny.yaml") + " --out " + out.string() + " --quiet --set input.files=[" +
                            xyz.string() + "] --set filters.outliers.enabled=false");
  EXPECT_EQ(o.status, 4) << o.output;
  EXPECT_NE(o.output.find("verdict fail"), std::string::npos) << o.output;
  EXPECT_NE(o.output.find("spikes_kept"), std::string::npos) << o.output;
  ASSERT_TRUE(fs::exists(out / "report.json")) << o.output;
  const json r = read_json(out / "report.json");
  EXPECT_EQ(r["verdict"]["status"].get<std::string>(), "fail");
  // The same file with the outlier stage on (the default) removes the point and passes.
  const fs::path out_ok = dir / "run_ok";
  const Outcome ok = run_app("run " + config("bunny.yaml") + " --out " + out_ok.string() + " --quiet --set input.files=[" +
                             xyz.string() + "]");
  EXPECT_EQ(ok.status, 0) << ok.output;
}

}  // namespace
