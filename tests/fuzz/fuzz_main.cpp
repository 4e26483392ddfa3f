// The libFuzzer entry point of one target: HC_FUZZ_TARGET names its function in fuzz_support.hpp
// (set per executable by tests/fuzz/CMakeLists.txt).
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  hc::fuzz::HC_FUZZ_TARGET(data, size);
  return 0;
}
