#include "hc/session/level_timing.hpp"

#include "hc/common/error.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/session/lod_controller.hpp"

#include <algorithm>
#include <chrono>
#include <string>

namespace hc::session {

void time_levels(const std::shared_ptr<pipeline::LodPyramid>& pyramid, std::vector<pipeline::LevelRow>& rows,
                 int ticks) {
  using Clock = std::chrono::steady_clock;
  const haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();
  for (pipeline::LevelRow& row : rows) {
    const int level = row.level;
    if (level < 0 || level >= pyramid->level_count()) {
      throw InputError("levels: row for level " + std::to_string(level) + " but the pyramid has levels 0.." +
                       std::to_string(pyramid->level_count() - 1));
    }
    const GridGeometry& g = pyramid->geometry(level);

    // Per-tick cost: a pressing circle on the centred window of this level.
    haptics::SharedState shared;
    LodControllerOptions lo;
    lo.device_half_extent_m = info.workspace_half_extent_m;
    lo.prefetch_neighbours = false;  // time this level alone, in the order of the table
    LodController lod(pyramid, shared, lo);
    const HapticWindow& w = lod.centre_window(level, g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.5 * (g.rows - 1)));
    haptics::ManualClock clock;
    haptics::ScriptedPath path;
    path.kind = haptics::PathKind::kCircle;
    path.half_x_m = 0.5 * info.workspace_half_extent_m.x();
    path.z_above_m = (w.max_height_m - w.map.origin_m.z()) / w.map.scale + 0.01;
    path.z_contact_m = -0.005;
    path.speed_m_per_s = 0.05;
    path.approach_s = 0.2;
    haptics::SimulatedDevice dev(clock, path, haptics::VirtualHand{}, info);
    dev.open();
    haptics::ServoConfig cfg;
    cfg.workspace = w.map;
    haptics::ServoLoop loop(dev, shared, clock, cfg);
    shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
    loop.run_ticks(static_cast<std::uint64_t>(std::max(ticks, 10)), clock);
    row.tick_p50_ns = loop.stats().compute.percentile_ns(0.5);
    row.tick_p99_ns = loop.stats().compute.percentile_ns(0.99);

    // Switch: from a neighbouring level to this one (levels cached), to the first tick on it.
    const int other = level + 1 < pyramid->level_count() ? level + 1 : std::max(0, level - 1);
    std::vector<double> ms;
    for (int k = 0; k < 5; ++k) {
      lod.set_level(other);
      loop.run_ticks(5, clock);
      haptics::Snapshot snap;
      shared.snapshots.read(snap);
      const auto t0 = Clock::now();
      lod.set_level(level, snap.proxy_m.eigen());
      loop.run_ticks(1, clock);
      ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      shared.collect_retired();
    }
    std::nth_element(ms.begin(), ms.begin() + 2, ms.end());
    row.switch_ms = ms[2];
    row.timed = true;
  }
}

pipeline::LevelTimingFn servo_level_timing(int ticks) {
  return [ticks](const std::shared_ptr<pipeline::LodPyramid>& pyramid, std::vector<pipeline::LevelRow>& rows) {
    time_levels(pyramid, rows, ticks);
  };
}

}  // namespace hc::session
