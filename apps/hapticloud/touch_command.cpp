// Placeholder registration until the haptic renderer lands (issue 3); replaced by its owner.
#include "commands.hpp"

namespace hc::app {
void add_touch_command(CLI::App& /*app*/) {}
}  // namespace hc::app
