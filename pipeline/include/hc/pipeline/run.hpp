#pragma once
/// @file run.hpp
/// The whole offline pipeline of `hapticloud run`: scan(s) → Monge grid → scene + report.

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Progress callback: called when a stage starts (done = false) and ends (done = true).
using ProgressFn = std::function<void(const StageReport& stage, bool done)>;

struct RunSummary {
  std::vector<StageReport> stages;
  std::optional<CrossCheck> cross_check;  ///< when enabled (cell_error_m holds the map)
  std::optional<CrossCheck> naive_cross_check;  ///< the naive front-most grid's, when compared
  GridGeometry grid;
  std::size_t valid_cells = 0;
  double total_seconds = 0.0;             ///< file to written report
  std::filesystem::path out_dir;
  std::filesystem::path moved_aside;      ///< where a foreign out_dir was kept (--force), or empty
};

/// Runs every stage of `config` and writes, atomically (StagingDir), the folder `out_dir`:
///   scene/ (scene.yaml + TIFF layers: depth, envelope, texture, mu_d, mu_s, cell_error),
///   previews/*.png, report.md and report.json.
/// Stages: ingest → units + recentre → view transform → filters → reproject → hole fill →
/// surface layers → cross-check → write.
/// An existing out_dir is replaced only if it is an earlier output or an empty folder; a file or
/// a foreign folder is refused, or kept aside with ExistingOutput::kMoveAside (see StagingDir).
/// @throws hc::Error subclasses from any stage (naming file, key or value), hc::InputError for a
///         refused out_dir (before any stage runs); on a throw nothing is left at out_dir that
///         was not there before.
RunSummary run_pipeline(const RunConfig& config, const std::filesystem::path& out_dir,
                        const ProgressFn& progress = {},
                        ExistingOutput existing = ExistingOutput::kRefuse);

/// SHA-256 of a file as lowercase hex. @throws hc::InputError naming the file if unreadable.
std::string sha256_file(const std::filesystem::path& file);

}  // namespace hc::pipeline
