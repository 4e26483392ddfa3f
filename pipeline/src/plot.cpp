#include "hc/pipeline/plot.hpp"

#include "hc/common/error.hpp"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

extern char** environ;

namespace hc::pipeline {

namespace {

namespace fs = std::filesystem;

[[noreturn]] void spec_error(const std::string& field, const std::string& expected) {
  throw ConfigError("plot spec: " + field + ": expected " + expected);
}

void validate(const PlotSpec& s) {
  if (s.output_png.empty()) spec_error("output_png", "a file path");
  if (s.title.empty()) spec_error("title", "a non-empty title");
  if (s.x_name.empty()) spec_error("x_name", "the quantity on the x axis, for example \"time\"");
  if (s.x_unit.empty()) spec_error("x_unit", "the unit of the x axis, for example \"s\" (\"-\" if dimensionless)");
  if (s.y_name.empty()) spec_error("y_name", "the quantity on the y axis, for example \"force\"");
  if (s.y_unit.empty()) spec_error("y_unit", "the unit of the y axis, for example \"N\" (\"-\" if dimensionless)");
  for (const auto& [name, v] : {std::pair{"width_px", s.width_px}, std::pair{"height_px", s.height_px}}) {
    if (v < 100 || v > 10000) spec_error(name, "a size in [100, 10000] pixels, got " + std::to_string(v));
  }
  if (s.series.empty()) spec_error("series", "at least one series");
  for (std::size_t i = 0; i < s.series.size(); ++i) {
    const PlotSeries& p = s.series[i];
    const std::string field = "series[" + std::to_string(i) + "] '" + p.name + "'";
    if (p.name.empty()) spec_error("series[" + std::to_string(i) + "].name", "a non-empty legend entry");
    if (p.x.size() != p.y.size()) {
      spec_error(field, "x and y of the same length, got " + std::to_string(p.x.size()) + " and " +
                            std::to_string(p.y.size()));
    }
    bool any_finite = false;
    for (std::size_t k = 0; k < p.x.size(); ++k) {
      if (std::isinf(p.x[k]) || std::isinf(p.y[k])) {
        spec_error(field, "finite values or NaN (a gap), got an infinite value at index " + std::to_string(k));
      }
      any_finite = any_finite || (std::isfinite(p.x[k]) && std::isfinite(p.y[k]));
    }
    if (!any_finite) spec_error(field, "at least one point with finite x and y");
  }
}

/// A gnuplot single-quoted string literal: inside '...' only the quote needs escaping (as '').
std::string quoted(const std::string& text) {
  std::string out = "'";
  for (char c : text) {
    if (c == '\'') {
      out += "''";
    } else if (c == '\n' || c == '\r') {
      out += ' ';
    } else {
      out += c;
    }
  }
  return out + "'";
}

void write_number(std::string& out, double v) {
  if (std::isnan(v)) {
    out += "NaN";
    return;
  }
  std::array<char, 32> buf{};
  const auto res = std::to_chars(buf.data(), buf.data() + buf.size(), v);
  out.append(buf.data(), res.ptr);
}

const char* style_clause(PlotStyle style) {
  switch (style) {
    case PlotStyle::kPoints: return "with points pt 7 ps 0.6";
    case PlotStyle::kLinesPoints: return "with linespoints lw 1.5 pt 7 ps 0.6";
    case PlotStyle::kLines: break;
  }
  return "with lines lw 1.5";
}

void write_file(const fs::path& path, const std::string& text) {
  std::ofstream os(path, std::ios::binary);
  os << text;
  os.close();
  if (!os) throw Error("plot: cannot write " + path.string());
}

std::string read_file(const fs::path& path) {
  std::ifstream is(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(is), std::istreambuf_iterator<char>());
}

/// Runs `gnuplot script` with stdout/stderr captured into files; returns the exit status
/// (or throws hc::Error if it cannot be started or is killed).
int run_gnuplot(const fs::path& script, const fs::path& out_log, const fs::path& err_log) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, out_log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, err_log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  std::string prog = "gnuplot";
  std::string arg = script.string();
  std::array<char*, 3> argv{prog.data(), arg.data(), nullptr};
  pid_t pid = 0;
  const int rc = posix_spawnp(&pid, "gnuplot", &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) {
    throw Error("plot: cannot start gnuplot (" + std::string(std::strerror(rc)) +
                "): it must be on PATH (Debian package gnuplot-nox)");
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) throw Error("plot: waiting for gnuplot failed: " + std::string(std::strerror(errno)));
  }
  if (WIFSIGNALED(status)) {
    throw Error("plot: gnuplot was killed by signal " + std::to_string(WTERMSIG(status)) + "; its stderr: " +
                read_file(err_log));
  }
  return WEXITSTATUS(status);
}

bool has_png_signature(const fs::path& path) {
  static constexpr unsigned char kSig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  std::ifstream is(path, std::ios::binary);
  char head[8] = {};
  is.read(head, 8);
  return is.gcount() == 8 && std::memcmp(head, kSig, 8) == 0;
}

fs::path unique_temp_dir() {
  static std::atomic<unsigned long> counter{0};
  const fs::path base = fs::temp_directory_path();
  for (int attempt = 0; attempt < 100; ++attempt) {
    const fs::path p = base / ("hc-plot-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
    std::error_code ec;
    if (fs::create_directory(p, ec)) return p;
    if (ec) throw Error("plot: cannot create a temporary folder under " + base.string() + ": " + ec.message());
  }
  throw Error("plot: cannot find a free temporary folder name under " + base.string());
}

}  // namespace

void plot_series(const PlotSpec& spec) {
  validate(spec);
  const fs::path output = fs::absolute(spec.output_png);
  std::error_code ec;
  if (output.has_parent_path()) {
    fs::create_directories(output.parent_path(), ec);
    if (ec) throw Error("plot: cannot create the folder of " + output.string() + ": " + ec.message());
  }
  const fs::path dir = unique_temp_dir();
  const fs::path data = dir / "series.dat";
  const fs::path script = dir / "plot.gp";
  const fs::path png = dir / "plot.png";

  std::string text;
  for (std::size_t i = 0; i < spec.series.size(); ++i) {
    const PlotSeries& s = spec.series[i];
    text += "# series " + std::to_string(i) + "\n";
    for (std::size_t k = 0; k < s.x.size(); ++k) {
      write_number(text, s.x[k]);
      text += ' ';
      write_number(text, s.y[k]);
      text += '\n';
    }
    text += "\n\n";  // two blank lines: the next gnuplot data index
  }
  write_file(data, text);

  std::ostringstream gp;
  const std::string size = std::to_string(spec.width_px) + "," + std::to_string(spec.height_px);
  gp << "if (strstrt(GPVAL_TERMINALS, 'pngcairo') > 0) {\n"
     << "  set terminal pngcairo size " << size << " noenhanced font ',11'\n"
     << "} else {\n"
     << "  set terminal png size " << size << " noenhanced\n"
     << "}\n"
     << "set output " << quoted(png.string()) << "\n"
     << "set title " << quoted(spec.title) << "\n"
     << "set xlabel " << quoted(spec.x_name + " [" + spec.x_unit + "]") << "\n"
     << "set ylabel " << quoted(spec.y_name + " [" + spec.y_unit + "]") << "\n"
     << "set grid\n"
     << "set key tmargin center horizontal box\n"
     << "plot ";
  for (std::size_t i = 0; i < spec.series.size(); ++i) {
    gp << (i ? ", \\\n     " : "") << quoted(data.string()) << " index " << i << " using 1:2 "
       << style_clause(spec.series[i].style) << " title " << quoted(spec.series[i].name);
  }
  gp << "\nunset output\n";
  write_file(script, gp.str());

  const fs::path out_log = dir / "gnuplot.out";
  const fs::path err_log = dir / "gnuplot.err";
  int status = 0;
  try {
    status = run_gnuplot(script, out_log, err_log);
  } catch (const Error&) {
    fs::remove_all(dir, ec);  // gnuplot never ran (or was killed): nothing worth keeping
    throw;
  }
  if (status != 0) {
    throw Error("plot: gnuplot failed (exit status " + std::to_string(status) + ") drawing " + output.string() +
                " from " + script.string() + " (kept for inspection); its stderr:\n" + read_file(err_log));
  }
  if (!fs::exists(png) || fs::file_size(png) == 0 || !has_png_signature(png)) {
    throw Error("plot: gnuplot exited cleanly but left no valid PNG for " + output.string() + " (script " +
                script.string() + ", kept); its stderr:\n" + read_file(err_log));
  }
  // Put the image in place: copy beside the target, then rename (atomic on one file system).
  const fs::path staged = output.string() + ".tmp-" + dir.filename().string();
  fs::copy_file(png, staged, fs::copy_options::overwrite_existing, ec);
  if (!ec) fs::rename(staged, output, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(staged, ignored);
    throw Error("plot: cannot write " + output.string() + ": " + ec.message());
  }
  fs::remove_all(dir, ec);  // best effort: a leftover temporary folder is harmless
}

}  // namespace hc::pipeline
