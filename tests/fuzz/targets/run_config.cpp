// Fuzz target: a YAML run config through hc::pipeline::parse_run_config (hc/pipeline/config.hpp),
// in memory. Paths in the config are only resolved, never opened, by the parser.
#include "../fuzz_support.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"

#include <string>

namespace hc::fuzz {

void run_config(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    (void)pipeline::parse_run_config(text, "fuzz/config.yaml");
  } catch (const hc::Error&) {
  }
}

}  // namespace hc::fuzz
