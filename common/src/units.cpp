#include "hc/common/units.hpp"

#include "hc/common/error.hpp"

namespace hc {

double metres_per_unit(std::string_view name) {
  if (name == "m") return 1.0;
  if (name == "cm") return 0.01;
  if (name == "mm") return 0.001;
  throw ConfigError("unknown length unit '" + std::string(name) + "' (expected one of: m, cm, mm)");
}

}  // namespace hc
