#include "hc/common/units.hpp"

#include "hc/common/error.hpp"

namespace hc {

double metres_per_unit(std::string_view name) {
  if (name == "m") return 1.0;
  if (name == "cm") return 0.01;
  if (name == "mm") return 0.001;
  if (name == "ft") return 0.3048;             // international foot (exact, 1959)
  if (name == "us-ft") return 1200.0 / 3937.0;  // US survey foot
  if (name == "in") return 0.0254;             // inch (exact)
  throw ConfigError("unknown length unit '" + std::string(name) + "' (expected one of: m, cm, mm, ft, us-ft, in)");
}

}  // namespace hc
