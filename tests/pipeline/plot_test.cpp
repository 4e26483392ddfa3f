#include "hc/pipeline/plot.hpp"

#include "hc/common/error.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;

PlotSpec two_series_spec(const fs::path& out) {
  PlotSpec s;
  s.output_png = out;
  s.title = "Proxy height on the sinusoid";
  s.x_name = "time";
  s.x_unit = "s";
  s.y_name = "proxy z";
  s.y_unit = "mm";
  s.width_px = 640;
  s.height_px = 480;
  PlotSeries a{"with texture and friction", {}, {}, PlotStyle::kLines};
  PlotSeries b{"without", {}, {}, PlotStyle::kPoints};
  for (int i = 0; i < 300; ++i) {
    const double t = 0.01 * i;
    a.x.push_back(t);
    a.y.push_back(i > 100 && i < 110 ? std::nan("") : std::sin(3 * t));  // NaN: a gap
    b.x.push_back(t);
    b.y.push_back(std::cos(3 * t));
  }
  s.series = {a, b};
  return s;
}

bool png_signature(const fs::path& p) {
  std::ifstream is(p, std::ios::binary);
  unsigned char head[8] = {};
  is.read(reinterpret_cast<char*>(head), 8);
  const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  return is.gcount() == 8 && std::equal(head, head + 8, sig);
}

TEST(Plot, WritesAPngOfTheRequestedSize) {
  const fs::path dir = hc::test::temp_dir("plot");
  // A folder that does not exist yet, a space and a quote in the name.
  const fs::path out = dir / "sub folder" / "proxy z's.png";
  PlotSpec spec = two_series_spec(out);
  spec.series[0].name = "with_underscores 'and quotes' μ_d";
  plot_series(spec);
  ASSERT_TRUE(fs::exists(out));
  EXPECT_GT(fs::file_size(out), 1000U);
  EXPECT_TRUE(png_signature(out));
  const cv::Mat img = cv::imread(out.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(img.empty());
  EXPECT_EQ(img.cols, 640);
  EXPECT_EQ(img.rows, 480);
  // Not a blank canvas: axes, text and two coloured series.
  cv::Mat gray;
  cv::cvtColor(img, gray, cv::COLOR_BGR2GRAY);
  cv::Scalar mean, stddev;
  cv::meanStdDev(gray, mean, stddev);
  EXPECT_GT(stddev[0], 5.0);
  // Nothing left beside the output (the staged copy was renamed onto it).
  int files = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(out.parent_path())) ++files;
  EXPECT_EQ(files, 1);
}

TEST(Plot, ReplacesAnExistingImage) {
  const fs::path out = hc::test::temp_dir("plot") / "p.png";
  { std::ofstream(out) << "old"; }
  PlotSpec spec = two_series_spec(out);
  spec.width_px = 300;
  spec.height_px = 200;
  plot_series(spec);
  const cv::Mat img = cv::imread(out.string());
  ASSERT_FALSE(img.empty());
  EXPECT_EQ(img.cols, 300);
  EXPECT_EQ(img.rows, 200);
}

TEST(Plot, RejectsIncompleteSpecsNamingTheField) {
  const fs::path out = hc::test::temp_dir("plot") / "never.png";
  const std::vector<std::pair<std::function<void(PlotSpec&)>, std::string>> cases = {
      {[](PlotSpec& s) { s.title.clear(); }, "title"},
      {[](PlotSpec& s) { s.x_unit.clear(); }, "x_unit"},
      {[](PlotSpec& s) { s.y_unit.clear(); }, "y_unit"},
      {[](PlotSpec& s) { s.y_name.clear(); }, "y_name"},
      {[](PlotSpec& s) { s.series.clear(); }, "series"},
      {[](PlotSpec& s) { s.series[1].y.pop_back(); }, "series[1] 'without'"},
      {[](PlotSpec& s) { s.series[0].name.clear(); }, "series[0].name"},
      {[](PlotSpec& s) { s.series[1].y[3] = INFINITY; }, "index 3"},
      {[](PlotSpec& s) { s.series[1].y.assign(s.series[1].y.size(), std::nan("")); }, "at least one point"},
      {[](PlotSpec& s) { s.width_px = 10; }, "width_px"},
  };
  for (const auto& [edit, needle] : cases) {
    PlotSpec spec = two_series_spec(out);
    edit(spec);
    try {
      plot_series(spec);
      ADD_FAILURE() << "expected ConfigError mentioning " << needle;
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  }
  EXPECT_FALSE(fs::exists(out));
}

/// Sets an environment variable for the duration of a test and restores it.
class EnvOverride {
 public:
  EnvOverride(const char* name, const std::string& value) : name_(name) {
    const char* old = std::getenv(name);
    had_ = old != nullptr;
    if (had_) saved_ = old;
    setenv(name, value.c_str(), 1);
  }
  ~EnvOverride() {
    if (had_) {
      setenv(name_, saved_.c_str(), 1);
    } else {
      unsetenv(name_);
    }
  }
  EnvOverride(const EnvOverride&) = delete;
  EnvOverride& operator=(const EnvOverride&) = delete;

 private:
  const char* name_;
  bool had_ = false;
  std::string saved_;
};

TEST(Plot, GnuplotFailureCarriesItsStderr) {
  const fs::path bin = hc::test::temp_dir("fake-gnuplot");
  const fs::path fake = bin / "gnuplot";
  {
    std::ofstream os(fake);
    os << "#!/bin/sh\necho 'line 7: simulated gnuplot failure' >&2\nexit 3\n";
  }
  fs::permissions(fake, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec);
  const fs::path out = bin / "out.png";
  const fs::path tmp = hc::test::temp_dir("tmp");  // the failed run's folder is kept here
  EnvOverride path("PATH", bin.string());
  EnvOverride tmpdir("TMPDIR", tmp.string());
  try {
    plot_series(two_series_spec(out));
    FAIL() << "expected hc::Error";
  } catch (const ConfigError&) {
    FAIL() << "a gnuplot failure is not a spec error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("simulated gnuplot failure"), std::string::npos) << msg;
    EXPECT_NE(msg.find("exit status 3"), std::string::npos) << msg;
    EXPECT_NE(msg.find((tmp / "hc-plot-").string()), std::string::npos) << msg;  // names the kept script
  }
  EXPECT_FALSE(fs::exists(out));
  int kept = 0;
  for (const auto& e : fs::directory_iterator(tmp)) kept += fs::exists(e.path() / "plot.gp") ? 1 : 0;
  EXPECT_EQ(kept, 1);
}

TEST(Plot, MissingGnuplotIsAnError) {
  const fs::path empty = hc::test::temp_dir("no-gnuplot");
  EnvOverride path("PATH", empty.string());
  EnvOverride tmpdir("TMPDIR", empty.string());
  try {
    plot_series(two_series_spec(empty / "out.png"));
    FAIL() << "expected hc::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("gnuplot"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace hc::pipeline
