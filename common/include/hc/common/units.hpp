#pragma once
/// @file units.hpp
/// Length units accepted in configs and their factor to SI metres.

#include <string>
#include <string_view>

namespace hc {

/// Metres per one unit of `name` ("m", "cm" or "mm").
/// @throws hc::ConfigError naming the value and the allowed set for any other name.
double metres_per_unit(std::string_view name);

}  // namespace hc
