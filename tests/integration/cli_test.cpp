// The program's conventions (issue 11 item 7, issue 15 D5): usage errors exit 2 with the usage
// line, input and config errors exit 1, -v/-q set the verbosity of every subcommand, and --out
// never replaces what hapticloud did not write.

#include <gtest/gtest.h>

#include "app_runner.hpp"
#include "test_paths.hpp"

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace {

namespace fs = std::filesystem;

std::string sinusoid() { return (fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml").string(); }

TEST(Cli, UsageErrorsExitTwoWithTheUsageLine) {
  std::string out;
  EXPECT_EQ(hc::test::run_app("frobnicate", &out), 2);
  EXPECT_NE(out.find("unknown subcommand 'frobnicate'"), std::string::npos) << out;
  EXPECT_NE(out.find("usage: hapticloud"), std::string::npos) << out;
  out.clear();
  EXPECT_EQ(hc::test::run_app("run", &out), 2);  // the config argument is missing
  EXPECT_NE(out.find("usage: hapticloud run"), std::string::npos) << out;
  out.clear();
  EXPECT_EQ(hc::test::run_app("run " + sinusoid() + " --no-such-option", &out), 2);
  EXPECT_NE(out.find("--no-such-option"), std::string::npos) << out;
  out.clear();
  EXPECT_EQ(hc::test::run_app("levels x --ticks 0", &out), 2);  // out of range: named
  EXPECT_NE(out.find("--ticks"), std::string::npos) << out;
}

TEST(Cli, InputErrorsExitOne) {
  const fs::path dir = hc::test::temp_dir("input");
  std::string out;
  EXPECT_EQ(hc::test::run_app("run " + (dir / "missing.yaml").string(), &out), 1);
  EXPECT_NE(out.find("missing.yaml"), std::string::npos) << out;
  std::ofstream(dir / "cfg.yaml") << "input: {files: [no_scan.ply]}\n";
  out.clear();
  EXPECT_EQ(hc::test::run_app("run " + (dir / "cfg.yaml").string() + " --out " + (dir / "o").string(), &out), 1);
  EXPECT_NE(out.find("no_scan.ply"), std::string::npos) << out;
}

TEST(Cli, VerboseAndQuietApplyToSubcommands) {
  const fs::path dir = hc::test::temp_dir("verbosity");
  const std::string base = "run " + sinusoid() + " --set grid.n=48 --set lod.report=false --out ";
  std::string quiet, normal, verbose;
  ASSERT_EQ(hc::test::run_app(base + (dir / "q").string() + " -q", &quiet), 0) << quiet;
  ASSERT_EQ(hc::test::run_app(base + (dir / "n").string(), &normal), 0) << normal;
  ASSERT_EQ(hc::test::run_app("-v " + base + (dir / "v").string(), &verbose), 0) << verbose;
  // Stage lines: none when quiet, one per stage normally, plus "stage ..." announcements when verbose.
  EXPECT_EQ(quiet.find("reproject:"), std::string::npos) << quiet;
  EXPECT_NE(normal.find("reproject:"), std::string::npos) << normal;
  EXPECT_EQ(normal.find("reproject ..."), std::string::npos) << normal;
  EXPECT_NE(verbose.find("reproject ..."), std::string::npos) << verbose;
  // The result lines on stdout are there in every mode.
  EXPECT_NE(quiet.find("cross-check:"), std::string::npos) << quiet;
}

TEST(Cli, OutIsRefusedOnAFileOrForeignFolderAndForceKeepsItAside) {
  const fs::path dir = hc::test::temp_dir("force");
  const std::string base = "run " + sinusoid() + " --set grid.n=32 --set lod.report=false -q --out ";
  { std::ofstream(dir / "notes.txt") << "mine"; }
  std::string out;
  EXPECT_EQ(hc::test::run_app(base + (dir / "notes.txt").string(), &out), 1);
  EXPECT_NE(out.find("--force"), std::string::npos) << out;
  std::ifstream in(dir / "notes.txt");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), "mine");

  fs::create_directories(dir / "photos");
  { std::ofstream(dir / "photos" / "temple.jpg") << "jpeg"; }
  out.clear();
  EXPECT_EQ(hc::test::run_app(base + (dir / "photos").string(), &out), 1);
  EXPECT_TRUE(fs::exists(dir / "photos" / "temple.jpg"));
  out.clear();
  ASSERT_EQ(hc::test::run_app(base + (dir / "photos").string() + " --force", &out), 0) << out;
  EXPECT_TRUE(fs::exists(dir / "photos" / "scene" / "scene.yaml"));
  bool kept = false;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().filename().string().rfind("photos.replaced-", 0) == 0) kept = fs::exists(e.path() / "temple.jpg");
  }
  EXPECT_TRUE(kept) << out;
}

}  // namespace

namespace {

// Issue 15 D4: bytes that are not UTF-8 in a PLY element name (or a file name) ended the run with
// "internal error: ... invalid UTF-8 byte" after all the work. Now the report is written.
TEST(Cli, NonUtf8BytesInAPlyEndInAValidReport) {
  const fs::path dir = hc::test::temp_dir("utf8");
  const fs::path ply = dir / "plane.ply";
  {
    std::ofstream out(ply, std::ios::binary);
    out << "ply\nformat ascii 1.0\nelement vertex 400\nproperty float x\nproperty float y\nproperty float z\n"
        << "element caf\xe9\xff 1\nproperty float v\nend_header\n";
    for (int i = 0; i < 20; ++i)
      for (int j = 0; j < 20; ++j) out << 0.001 * i << " " << 0.001 * j << " " << 0.0001 * ((i + j) % 3) << "\n";
    out << "1\n";
  }
  std::ofstream(dir / "run.yaml") << "input: {files: [plane.ply]}\ngrid: {n: 20}\nlod: {report: false}\n";
  std::string out;
  ASSERT_EQ(hc::test::run_app("run " + (dir / "run.yaml").string() + " -q --out " + (dir / "out").string(), &out), 0)
      << out;
  const nlohmann::json r = hc::test::read_json(dir / "out" / "report.json");  // throws if not valid JSON
  EXPECT_EQ(r["grid"]["cols"].get<int>(), 20);
}

}  // namespace
