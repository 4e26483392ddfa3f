// Fuzz target: a scanalyze .conf through hc::pipeline::read_scanalyze_conf (hc/pipeline/ingest.hpp).
#include "../fuzz_support.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"

namespace hc::fuzz {

void scanalyze_conf(const std::uint8_t* data, std::size_t size) {
  const auto path = write_scratch("scans.conf", data, size);
  try {
    for (const auto& pose : pipeline::read_scanalyze_conf(path)) (void)pose.scan_to_world();
  } catch (const hc::Error&) {
  }
}

}  // namespace hc::fuzz
