#include "hc/common/cell_buffer.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <string>

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

namespace hc {

namespace {

[[noreturn]] void fail(const std::filesystem::path& dir, std::size_t bytes, const std::string& what, const char* step, int err) {
  throw ResourceError("cannot " + std::string(step) + " a file of " + std::to_string(bytes) + " bytes in " + dir.string() + " for " +
                      what + ": " + std::strerror(err) +
                      (err == ENOSPC ? " (the disk is full: expected room for it there; a run's scratch folder is scale.scratch, "
                                       "tile-merge's the plan's folder)"
                                     : ""));
}

}  // namespace

ScratchMapping::ScratchMapping(const std::filesystem::path& dir, std::size_t bytes, const std::string& what) : bytes_(bytes) {
  std::string name = (dir / "layer-XXXXXX").string();
  const int fd = ::mkstemp(name.data());
  if (fd < 0) fail(dir, bytes, what, "create", errno);
  // Unlinked at once: the mapping keeps the file's blocks until it goes, and nothing stays in
  // the folder whatever ends the process.
  (void)::unlink(name.c_str());
  // Every block reserved now (posix_fallocate returns the error, it does not set errno).
  int e = 0;
  do {
    e = ::posix_fallocate(fd, 0, static_cast<off_t>(bytes));
  } while (e == EINTR);  // a signal during a large reservation
  if (e != 0) {
    ::close(fd);
    fail(dir, bytes, what, "reserve", e);
  }
  void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  e = errno;
  ::close(fd);  // the mapping holds the file
  if (p == MAP_FAILED) fail(dir, bytes, what, "map", e);
  data_ = p;
}

ScratchMapping::~ScratchMapping() {
  if (data_ != nullptr) (void)::munmap(data_, bytes_);
}

void ScratchMapping::release_resident() const {
  // For a shared file mapping, MADV_DONTNEED unmaps the pages; their written contents stay in
  // the page cache (a dirty page stays dirty there and is written back), and a later access
  // maps the file's up-to-date contents again (madvise(2)).
  if (data_ != nullptr && bytes_ >= kReleaseAboveBytes) (void)::madvise(data_, bytes_, MADV_DONTNEED);
}

void ScratchMapping::release_resident(std::size_t offset, std::size_t count) const {
  if (data_ == nullptr || bytes_ < kReleaseAboveBytes || offset >= bytes_) return;
  const std::size_t end = offset + std::min(count, bytes_ - offset);
  const auto page = static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
  // The mapping starts on a page (mmap), so whole pages of it are whole pages of memory.
  const std::size_t lo = (offset + page - 1) / page * page, hi = end / page * page;
  if (hi > lo) (void)::madvise(static_cast<char*>(data_) + lo, hi - lo, MADV_DONTNEED);
}

}  // namespace hc
