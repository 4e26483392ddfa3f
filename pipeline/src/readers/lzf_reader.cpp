// LZF data decompressed as they are read (lzf_reader.hpp).

#include "lzf_reader.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cstring>
#include <utility>

namespace hc::pipeline::detail {

LzfReader::LzfReader(std::uint64_t compressed_bytes, std::uint64_t decompressed_bytes, Fill fill, std::string what)
    : compressed_(compressed_bytes), decompressed_(decompressed_bytes), fill_(std::move(fill)), what_(std::move(what)),
      in_(std::size_t{1} << 18), win_(kReach + kSpan + kLongest) {}

void LzfReader::fail(const std::string& why) const { throw InputError(what_ + ": " + why); }

unsigned char LzfReader::byte(const char* need) {
  if (in_at_ == in_end_) {
    const std::uint64_t left = compressed_ - in_read_;
    if (left == 0) {
      fail("the " + std::to_string(compressed_) + " compressed bytes end inside an instruction (" + need + ")");
    }
    const auto want = static_cast<std::size_t>(std::min<std::uint64_t>(in_.size(), left));
    const std::size_t got = fill_(in_.data(), want);
    if (got == 0) {
      fail("the file ends after " + std::to_string(in_read_) + " of the " + std::to_string(compressed_) + " compressed bytes");
    }
    in_read_ += got;
    in_at_ = 0;
    in_end_ = got;
  }
  return static_cast<unsigned char>(in_[in_at_++]);
}

bool LzfReader::step() {
  const std::uint64_t at_byte = in_read_ - (in_end_ - in_at_);  // this instruction's compressed offset
  if (at_byte == compressed_) return false;
  if (end_ + kLongest > win_.size()) {
    // Keep what is not yet taken and the last kReach bytes (a reference's farthest reach).
    const std::size_t keep_from = std::min(at_, end_ > kReach ? end_ - kReach : std::size_t{0});
    std::memmove(win_.data(), win_.data() + keep_from, end_ - keep_from);
    at_ -= keep_from;
    end_ -= keep_from;
  }
  const auto where = [&] { return "at compressed byte " + std::to_string(at_byte) + " (output byte " + std::to_string(produced_) + ")"; };
  const unsigned c = byte("a control byte");
  std::size_t len = 0;
  if (c < 32) {  // a literal run of c + 1 bytes
    len = c + 1;
    if (produced_ + len > decompressed_) {
      fail("corrupt " + where() + ": a literal run past the " + std::to_string(decompressed_) + " bytes the header declares");
    }
    if (in_end_ - in_at_ >= len) {
      std::memcpy(win_.data() + end_, in_.data() + in_at_, len);
      in_at_ += len;
    } else {
      for (std::size_t i = 0; i < len; ++i) win_[end_ + i] = static_cast<char>(byte("a literal run"));
    }
  } else {  // a back reference
    len = c >> 5;
    std::size_t back = (static_cast<std::size_t>(c & 31) << 8) + 1;
    if (len == 7) len += byte("a back reference's length");
    back += byte("a back reference's offset");
    len += 2;
    if (produced_ + len > decompressed_) {
      fail("corrupt " + where() + ": a back reference past the " + std::to_string(decompressed_) + " bytes the header declares");
    }
    if (back > produced_) {
      fail("corrupt " + where() + ": a back reference " + std::to_string(back) + " bytes back, before the data's start");
    }
    // The window holds min(produced_, kReach) bytes at least before end_ (the shift above), and
    // back ≤ kReach. Byte by byte where the copy overlaps its source.
    char* dst = win_.data() + end_;
    const char* src = dst - back;
    if (back >= len) {
      std::memcpy(dst, src, len);
    } else {
      for (std::size_t i = 0; i < len; ++i) dst[i] = src[i];
    }
  }
  end_ += len;
  produced_ += len;
  return true;
}

void LzfReader::read(char* out, std::size_t n) {
  while (n > 0) {
    if (at_ == end_) {
      if (!step()) {
        fail("the " + std::to_string(compressed_) + " compressed bytes give " + std::to_string(produced_) + " bytes, the header declares " +
             std::to_string(decompressed_));
      }
      continue;
    }
    const std::size_t take = std::min(n, end_ - at_);
    if (out != nullptr) {
      std::memcpy(out, win_.data() + at_, take);
      out += take;
    }
    at_ += take;
    taken_ += take;
    n -= take;
  }
}

void LzfReader::finish() {
  while (step()) {
    taken_ += end_ - at_;
    at_ = end_;
  }
  taken_ += end_ - at_;
  at_ = end_;
  if (produced_ != decompressed_) {
    fail("the " + std::to_string(compressed_) + " compressed bytes give " + std::to_string(produced_) + " bytes, the header declares " +
         std::to_string(decompressed_));
  }
}

}  // namespace hc::pipeline::detail
