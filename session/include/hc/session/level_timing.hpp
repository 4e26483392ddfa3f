#pragma once
/// @file level_timing.hpp
/// The servo columns of the levels table (`hapticloud levels` and the run report): per level,
/// the servo tick's compute time on a centred haptic window and the time from a level-switch
/// request to the first tick on the new window. The pipeline builds and cross-checks the levels
/// (hc/pipeline/lod_report.hpp); these columns need a servo loop, so they live here.

#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/run.hpp"

#include <memory>
#include <vector>

namespace hc::session {

/// Fills tick_p50_ns, tick_p99_ns and switch_ms of every row (and sets `timed`): for row L, a
/// simulated device (hc::haptics::SimulatedDevice's default workspace, a pressing circle through a
/// virtual hand) drives a servo loop on a ManualClock, as fast as possible, for `ticks` ticks on
/// the window of level L centred on the level; then five switches from a neighbouring level to L
/// (both cached) are timed from the request to the end of the first tick on L, and the median
/// kept. Levels are built through the pyramid if not cached.
/// @param rows one row per level, as pipeline::level_table made them (row.level indexes the pyramid)
/// @param ticks servo ticks timed per level, ≥ 10 (smaller values are raised to 10)
/// @throws hc::InputError for a row whose level is not in the pyramid. Real-time: no.
/// Wall-clock figures: they depend on the machine and its load (medians, never asserted).
void time_levels(const std::shared_ptr<pipeline::LodPyramid>& pyramid, std::vector<pipeline::LevelRow>& rows,
                 int ticks = 3000);

/// time_levels as the run report's hook (pipeline::run_pipeline's `level_timing` argument).
pipeline::LevelTimingFn servo_level_timing(int ticks = 3000);

}  // namespace hc::session
