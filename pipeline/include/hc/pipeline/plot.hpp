#pragma once
/// @file plot.hpp
/// Line plots (PNG) drawn by gnuplot, driven from the program: axes with quantity and unit,
/// a title and a legend. Used for the touch-session and validation plots (issue 3).

#include <filesystem>
#include <string>
#include <vector>

namespace hc::pipeline {

/// How one series is drawn.
enum class PlotStyle { kLines, kPoints, kLinesPoints };

/// One named series: y[i] against x[i]. NaN in x or y leaves a gap in the line.
struct PlotSeries {
  std::string name;        ///< legend entry (plain text, no markup), non-empty
  std::vector<double> x;   ///< abscissae in the unit of PlotSpec::x_unit
  std::vector<double> y;   ///< ordinates in the unit of PlotSpec::y_unit, same length as x
  PlotStyle style = PlotStyle::kLines;
};

/// A whole figure. Axis labels read "x_name [x_unit]"; use "-" as the unit of a dimensionless
/// quantity.
struct PlotSpec {
  std::filesystem::path output_png;  ///< written (replaced) by plot_series; parent folders created
  std::string title;                 ///< figure title, non-empty
  std::string x_name;                ///< for example "time", non-empty
  std::string x_unit;                ///< for example "s", non-empty
  std::string y_name;                ///< for example "proxy z", non-empty
  std::string y_unit;                ///< for example "mm", non-empty
  std::vector<PlotSeries> series;    ///< at least one, each with at least one point
  int width_px = 900;                ///< image width [px], 100..10000
  int height_px = 600;               ///< image height [px], 100..10000
};

/// Draws the series into `spec.output_png` with gnuplot (terminal pngcairo when this gnuplot has
/// it, else png): data and script go to a fresh temporary folder, `gnuplot` (found on PATH) runs
/// on the script, and the folder is removed on success (kept, and named in the message, on
/// failure). Thread-safe (each call uses its own folder); not real-time (spawns a process).
/// @throws hc::ConfigError if the spec is incomplete (names the field and what is expected);
///         hc::Error if gnuplot cannot be started, fails (the message holds its stderr) or
///         leaves no PNG.
void plot_series(const PlotSpec& spec);

}  // namespace hc::pipeline
