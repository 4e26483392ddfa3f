#pragma once
// Whole positional reads and writes of a file descriptor, retried after a signal (EINTR: a
// libFuzzer timer, the run's signal watcher) and after a short count: the tiled run's spill,
// block copies and re-marking (tiled_run.cpp), and the LAZ and E57 readers' chunks and pages.
// Private to the pipeline (not installed).

#include <cerrno>
#include <cstddef>
#include <cstdint>

#include <sys/types.h>
#include <unistd.h>

namespace hc::pipeline::detail {

/// Reads `bytes` bytes at offset `at` (bytes from the file's start) of `fd` into `to`
/// (pread(2), repeated). Returns false when a read fails (errno tells why) or the file ends
/// first (errno unchanged); `to` then holds what was read. Never throws.
inline bool pread_full(int fd, void* to, std::size_t bytes, std::uint64_t at) {
  auto* p = static_cast<char*>(to);
  std::size_t got = 0;
  while (got < bytes) {
    const ssize_t r = ::pread(fd, p + got, bytes - got, static_cast<off_t>(at + got));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) return false;
    got += static_cast<std::size_t>(r);
  }
  return true;
}

/// Writes `bytes` bytes from `from` at offset `at` of `fd` (pwrite(2), repeated). Returns false
/// when a write fails (errno tells why, as ENOSPC) or writes nothing. Never throws.
inline bool pwrite_full(int fd, const void* from, std::size_t bytes, std::uint64_t at) {
  const auto* p = static_cast<const char*>(from);
  std::size_t put = 0;
  while (put < bytes) {
    const ssize_t w = ::pwrite(fd, p + put, bytes - put, static_cast<off_t>(at + put));
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    put += static_cast<std::size_t>(w);
  }
  return true;
}

}  // namespace hc::pipeline::detail
