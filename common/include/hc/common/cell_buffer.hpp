#pragma once
/// @file cell_buffer.hpp
/// The cells of a grid layer: on the heap, or in a shared mapping of a scratch file, so that a
/// level 0 larger than the machine's memory is held by the kernel's page cache, which writes it
/// to the file and drops it under memory pressure (docs/scale.md, "Level 0 in a file").

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace hc {

/// A shared, writable mapping of a new scratch file of `bytes` bytes (Linux mmap(2),
/// MAP_SHARED). The file is reserved in full first (posix_fallocate), so that a full disk is an
/// error here and not a SIGBUS at a later write (on file systems that write in place, such as
/// ext4 and XFS; a copy-on-write one, btrfs or ZFS, may still need new blocks at write-back),
/// and it is unlinked as soon as it is mapped: nothing is left in the folder, whatever ends the
/// process; its blocks are freed at unmapping.
class ScratchMapping {
 public:
  /// @param dir   an existing folder on a file system that supports mmap (the run's scratch
  ///              folder, scale.scratch).
  /// @param bytes size of the mapping [bytes], > 0.
  /// @param what  what the mapping holds, for the error message ("level 0's depth").
  /// @throws ResourceError naming `dir`, the bytes and `what` when the file cannot be created,
  ///         reserved (ENOSPC: the disk is full) or mapped.
  ScratchMapping(const std::filesystem::path& dir, std::size_t bytes, const std::string& what);
  ~ScratchMapping();
  ScratchMapping(const ScratchMapping&) = delete;
  ScratchMapping& operator=(const ScratchMapping&) = delete;

  void* data() const { return data_; }
  std::size_t bytes() const { return bytes_; }
  /// Drops the mapping's pages from this process's resident set (madvise MADV_DONTNEED): what
  /// was written stays in the page cache and the file, and the next read maps it again. Reads
  /// and writes may go on at once from other threads (they map the pages again); no-op on
  /// failure (the pages stay resident, as before the call), and for a mapping smaller than
  /// kReleaseAboveBytes, whose pages would cost more to fault in again than they hold (a tiled
  /// run gives a small grid's level 0 back after every tile: 7 % more CPU on the Buddha in
  /// 64-cell tiles, measured 2026-12-01).
  void release_resident() const;
  /// The same for the whole pages inside bytes [offset, offset + count) of the mapping (a range
  /// beyond its end is clipped; the partial pages at either end stay): a sweep gives back what
  /// it has passed while other threads keep their own parts resident.
  void release_resident(std::size_t offset, std::size_t count) const;
  static constexpr std::size_t kReleaseAboveBytes = std::size_t{32} << 20;

 private:
  void* data_ = nullptr;
  std::size_t bytes_ = 0;
};

/// How often a sweep over a file-backed layer gives its pages back [cells]: every 4 Mi cells
/// (16 MiB of floats), so that a sweep holds at most that much of each layer resident.
inline constexpr std::size_t kReleaseEveryCells = std::size_t{1} << 22;

/// `size()` cells of trivially copyable T, contiguous: a std::vector<T> on the heap (the
/// default), or a ScratchMapping (file_backed()). The interface is the part of std::vector's
/// that a grid layer uses: a buffer's size is set when it is made. Copies are on the heap;
/// moves keep the storage. Equality compares the cells (NaN ≠ NaN, as std::vector<float>).
template <class T>
class CellBuffer {
 public:
  using value_type = T;
  using size_type = std::size_t;
  using iterator = T*;
  using const_iterator = const T*;
  using reference = T&;
  using const_reference = const T&;

  CellBuffer() = default;
  /// `n` cells of `fill`, on the heap.
  CellBuffer(std::size_t n, const T& fill) : heap_(n, fill) { point_at_heap(); }
  /// `n` cells of `fill` in a ScratchMapping in `dir` (see there; throws ResourceError).
  CellBuffer(const std::filesystem::path& dir, std::size_t n, const T& fill, const std::string& what) {
    if (n == 0) return;
    file_ = std::make_shared<ScratchMapping>(dir, n * sizeof(T), what);
    data_ = static_cast<T*>(file_->data());
    size_ = n;
    // A fill of zero bytes is what the reserved file reads as already: nothing to write.
    const T zero{};
    if (std::memcmp(&fill, &zero, sizeof(T)) == 0) return;
    // Filled a block at a time, each block's pages given back (the page cache keeps them).
    for (std::size_t i = 0; i < n; i += kReleaseEveryCells) {
      std::fill(data_ + i, data_ + std::min(n, i + kReleaseEveryCells), fill);
      file_->release_resident();
    }
  }
  /// The cells of `v`, on the heap (moved, not copied).
  CellBuffer(std::vector<T>&& v) : heap_(std::move(v)) { point_at_heap(); }  // NOLINT(google-explicit-constructor): a move

  CellBuffer(const CellBuffer& o) : heap_(o.begin(), o.end()) { point_at_heap(); }
  CellBuffer& operator=(const CellBuffer& o) {
    if (this != &o) *this = CellBuffer(o);
    return *this;
  }
  CellBuffer(CellBuffer&& o) noexcept { swap(o); }
  CellBuffer& operator=(CellBuffer&& o) noexcept {
    CellBuffer gone(std::move(o));
    swap(gone);
    return *this;
  }
  /// Takes `v`'s cells (on the heap); the storage held before is let go.
  CellBuffer& operator=(std::vector<T>&& v) { return *this = CellBuffer(std::move(v)); }
  /// `n` cells of `fill` on the heap (std::vector::assign); the storage held before is let go.
  void assign(std::size_t n, const T& fill) { *this = CellBuffer(n, fill); }
  /// No cells; the storage held before is let go.
  void clear() { *this = CellBuffer(); }

  std::size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  T* data() { return data_; }
  const T* data() const { return data_; }
  T& operator[](std::size_t i) { return data_[i]; }
  const T& operator[](std::size_t i) const { return data_[i]; }
  T* begin() { return data_; }
  T* end() { return data_ + size_; }
  const T* begin() const { return data_; }
  const T* end() const { return data_ + size_; }

  /// True where the cells are in a ScratchMapping.
  bool file_backed() const { return file_ != nullptr; }
  /// A file-backed buffer's pages dropped from the resident set (ScratchMapping::
  /// release_resident); nothing for one on the heap.
  void release_resident() const {
    if (file_) file_->release_resident();
  }
  /// The pages of cells [first, first + count) only (ScratchMapping::release_resident(offset,
  /// count): whole pages inside the range); nothing for a buffer on the heap.
  void release_resident(std::size_t first, std::size_t count) const {
    if (file_) file_->release_resident(first * sizeof(T), count * sizeof(T));
  }

  friend bool operator==(const CellBuffer& a, const CellBuffer& b) { return std::equal(a.begin(), a.end(), b.begin(), b.end()); }

 private:
  void point_at_heap() {
    data_ = heap_.data();
    size_ = heap_.size();
  }
  void swap(CellBuffer& o) noexcept {
    heap_.swap(o.heap_);
    file_.swap(o.file_);
    std::swap(data_, o.data_);
    std::swap(size_, o.size_);
  }
  std::vector<T> heap_;
  std::shared_ptr<ScratchMapping> file_;
  T* data_ = nullptr;
  std::size_t size_ = 0;
};

}  // namespace hc
