// ByteSource (byte_source.hpp): plain files through stdio, gzip files through zlib's inflate
// (RFC 1952 members in turn), each read error an InputError naming the file.

#include "byte_source.hpp"

#include "hc/common/error.hpp"

#include <zlib.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstring>
#include <vector>

namespace hc::pipeline::detail {

namespace {

class PlainSource final : public ByteSource {
 public:
  PlainSource(std::FILE* f, std::string name) : ByteSource(std::move(name), large_file_key(fileno(f))), f_(f) {}
  ~PlainSource() override { std::fclose(f_); }

  std::size_t read(char* out, std::size_t n) override {
    const std::size_t got = std::fread(out, 1, n, f_);
    if (got < n && std::ferror(f_)) throw InputError("load_cloud: " + name_ + ": read error: " + std::strerror(errno));
    return got;
  }
  void seek(std::uint64_t offset) override {
    if (offset > static_cast<std::uint64_t>(LLONG_MAX) || ::fseeko(f_, static_cast<off_t>(offset), SEEK_SET) != 0) {
      throw InputError("load_cloud: " + name_ + ": cannot seek to byte " + std::to_string(offset));
    }
  }

 private:
  std::FILE* f_;
};

// gzip inflated as it is read, with zlib's inflate exactly as load_cloud's whole read inflates a
// .gz (ingest.cpp, gunzip): the header detected (gzip or zlib, 15 + 32), a member that ends with
// more bytes after it followed by the next, and the same errors in the same words: data that end
// inside a member are "truncated", anything else zlib refuses (trailing bytes that are not a
// member among it) is "not valid gzip data (zlib: …)", and data that decompress to nothing are
// refused at their end.
class GzSource final : public ByteSource {
 public:
  GzSource(int fd, std::string name, std::uint64_t file_bytes)
      : ByteSource(std::move(name), large_file_key(fd)), fd_(fd), file_bytes_(file_bytes), in_(kIn) {
    if (inflateInit2(&zs_, 15 + 32) != Z_OK) {
      ::close(fd_);
      throw ResourceError("load_cloud: zlib could not initialise an inflate stream for " + name_);
    }
  }
  ~GzSource() override {
    inflateEnd(&zs_);
    ::close(fd_);
  }

  std::size_t read(char* out, std::size_t n) override {
    std::size_t done = 0;
    while (done < n && !ended_) {
      if (zs_.avail_in == 0 && !file_end_) refill();
      const auto ask = static_cast<uInt>(std::min<std::size_t>(n - done, std::size_t{1} << 30));
      zs_.next_out = reinterpret_cast<Bytef*>(out + done);
      zs_.avail_out = ask;
      const int rc = inflate(&zs_, Z_NO_FLUSH);
      const std::size_t got = ask - zs_.avail_out;
      done += got;
      produced_ += got;
      if (rc == Z_STREAM_END) {
        if (zs_.avail_in == 0 && !file_end_) refill();
        if (zs_.avail_in == 0) {  // every byte of the file inflated
          ended_ = true;
          if (produced_ == 0) throw gzip_empty_error(name_);
          break;
        }
        if (inflateReset(&zs_) != Z_OK) fail(rc);  // another member follows (`cat a.gz b.gz`)
        continue;
      }
      if (rc == Z_BUF_ERROR && zs_.avail_in == 0 && file_end_) fail(rc);  // the input ended inside a member
      if (rc != Z_OK && rc != Z_BUF_ERROR) fail(rc);
    }
    return done;
  }

  void seek(std::uint64_t offset) override {
    if (offset < produced_) {  // back to the start: inflate again from the file's first byte
      if (::lseek(fd_, 0, SEEK_SET) != 0 || inflateReset(&zs_) != Z_OK) {
        throw InputError("load_cloud: " + name_ + ": cannot go back to the start of its gzip data");
      }
      zs_.avail_in = 0;
      file_end_ = ended_ = false;
      produced_ = 0;
    }
    std::vector<char> skip(1u << 16);
    while (produced_ < offset) {
      const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(offset - produced_, skip.size()));
      if (read(skip.data(), want) < want) {
        throw InputError("load_cloud: " + name_ + ": its gzip data end before byte " + std::to_string(offset));
      }
    }
  }

  void drain() override {
    std::vector<char> rest(1u << 16);
    while (read(rest.data(), rest.size()) == rest.size()) {
    }
  }

 private:
  static constexpr std::size_t kIn = std::size_t{1} << 20;
  void refill() {
    const ::ssize_t got = ::read(fd_, in_.data(), in_.size());
    if (got < 0) throw InputError("load_cloud: " + name_ + ": read error: " + std::strerror(errno));
    zs_.next_in = reinterpret_cast<Bytef*>(in_.data());
    zs_.avail_in = static_cast<uInt>(got);
    file_end_ = got == 0 || static_cast<std::size_t>(got) < in_.size();
  }
  [[noreturn]] void fail(int rc) {
    throw gzip_data_error(name_, rc == Z_BUF_ERROR || rc == Z_OK || rc == Z_STREAM_END, zs_.msg, file_bytes_);
  }

  int fd_;
  std::uint64_t file_bytes_;
  std::vector<char> in_;
  z_stream zs_{};
  bool file_end_ = false, ended_ = false;
  std::uint64_t produced_ = 0;  // decompressed bytes handed out (or skipped) since the start
};

}  // namespace

std::unique_ptr<ByteSource> ByteSource::open(const std::filesystem::path& path, const std::string& name, bool gz) {
  if (!gz) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (f == nullptr) throw InputError("load_cloud: " + name + ": cannot open it: " + std::strerror(errno));
    struct stat st {};
    if (::fstat(fileno(f), &st) == 0 && st.st_size == 0) {
      std::fclose(f);
      throw empty_file_error(name);
    }
    return std::make_unique<PlainSource>(f, name);
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError("load_cloud: " + name + ": cannot open it: " + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || st.st_size == 0) {
    ::close(fd);
    throw empty_file_error(name);
  }
  return std::make_unique<GzSource>(fd, name, static_cast<std::uint64_t>(st.st_size));
}

InputError empty_file_error(const std::string& name) { return InputError("load_cloud: file " + name + " is empty (0 bytes)"); }

InputError gzip_data_error(const std::string& name, bool truncated, const char* zlib_msg, std::uint64_t compressed_bytes) {
  if (truncated) {
    return InputError("load_cloud: gzip data of " + name + " is truncated (stream ended after " + std::to_string(compressed_bytes) +
                      " compressed bytes)");
  }
  return InputError("load_cloud: " + name + " is not valid gzip data" + (zlib_msg != nullptr ? " (zlib: " + std::string(zlib_msg) + ")" : ""));
}

InputError gzip_empty_error(const std::string& name) { return InputError("load_cloud: " + name + " decompresses to 0 bytes"); }

std::size_t read_header_until_word(ByteSource& src, std::string_view word, std::string& head, bool unterminated_last,
                                   std::size_t max_bytes) {
  std::vector<char> block(65536);
  std::size_t line_from = 0;  // the first line not yet looked at
  while (head.size() < max_bytes) {
    const std::size_t got = src.read(block.data(), block.size());
    const bool at_end = got == 0;
    head.append(block.data(), got);
    for (;;) {
      std::size_t nl = head.find('\n', line_from);
      if (nl == std::string::npos) {
        if (!(at_end && unterminated_last) || line_from >= head.size()) break;
        nl = head.size();  // the data's last line, unterminated
      }
      const auto space = [&](std::size_t i) { return std::isspace(static_cast<unsigned char>(head[i])) != 0; };
      std::size_t b = line_from;
      while (b < nl && space(b)) ++b;
      std::size_t e = b;
      while (e < nl && !space(e)) ++e;
      if (std::string_view(head).substr(b, e - b) == word) return std::min(nl + 1, head.size());
      line_from = nl + 1;
    }
    if (at_end) break;
  }
  return std::string::npos;
}

bool gz_name(const std::filesystem::path& path, std::string& inner_ext) {
  std::string file = path.filename().string();
  std::transform(file.begin(), file.end(), file.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  const bool gz = file.size() > 3 && file.compare(file.size() - 3, 3, ".gz") == 0;
  if (gz) file.resize(file.size() - 3);
  inner_ext = std::filesystem::path(file).extension().string();
  return gz;
}

}  // namespace hc::pipeline::detail
