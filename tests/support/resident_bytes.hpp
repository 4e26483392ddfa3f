#pragma once
// The resident size of one mapping of this process, read from the kernel (Linux
// /proc/self/smaps, proc(5)): the oracle of the tests that check a file-backed layer's pages go
// back (CellBuffer::release_resident), independent of the code under test.

#include <cstdint>
#include <fstream>
#include <sstream>
#include <string>

namespace hc::test {

/// The resident size [bytes] of this process's mapping that holds `p` (its `Rss:` line in
/// /proc/self/smaps, in KiB there); -1 where no mapping holds it.
inline long long resident_bytes_of_mapping(const void* p) {
  std::ifstream in("/proc/self/smaps");
  const auto at = reinterpret_cast<std::uintptr_t>(p);
  bool inside = false;
  for (std::string line; std::getline(in, line);) {
    unsigned long long lo = 0, hi = 0;
    char dash = 0;
    std::istringstream head(line);
    if (head >> std::hex >> lo >> dash >> hi && dash == '-') {
      inside = at >= lo && at < hi;
      continue;
    }
    if (inside && line.rfind("Rss:", 0) == 0) return std::stoll(line.substr(4)) * 1024;
  }
  return -1;
}

}  // namespace hc::test
