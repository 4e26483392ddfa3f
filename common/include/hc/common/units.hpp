#pragma once
/// @file units.hpp
/// Length units accepted in configs and their factor to SI metres.

#include <string>
#include <string_view>

namespace hc {

/// Metres per one unit of `name`: "m" 1, "cm" 0.01, "mm" 0.001, "ft" 0.3048 (international
/// foot), "us-ft" 1200/3937 (US survey foot, as in EPSG unit 9003), "in" 0.0254.
/// Source: NIST SP 811 (exact definitions of the foot, inch and US survey foot).
/// @throws hc::ConfigError naming the value and the allowed set for any other name.
double metres_per_unit(std::string_view name);

}  // namespace hc
