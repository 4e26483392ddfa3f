// Fuzz target: a .e57 scan file through hc::pipeline::load_cloud (hc/pipeline/ingest.hpp).
#include "../fuzz_support.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"

namespace hc::fuzz {

void e57(const std::uint8_t* data, std::size_t size) {
  const auto path = write_scratch("scan.e57", data, size);
  try {
    (void)pipeline::load_cloud(path);
  } catch (const hc::Error&) {
    // a clear refusal is a correct answer to bad bytes
  }
}

}  // namespace hc::fuzz
