// ByteSource (byte_source.hpp): plain files through stdio, gzip files through zlib's gz*
// functions (RFC 1952 members in turn), each read error an InputError naming the file.

#include "byte_source.hpp"

#include "hc/common/error.hpp"

#include <zlib.h>

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstring>

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

class GzSource final : public ByteSource {
 public:
  GzSource(int fd, std::string name) : ByteSource(std::move(name), large_file_key(fd)), g_(gzdopen(fd, "rb")) {
    if (g_ == nullptr) {
      ::close(fd);
      throw InputError("load_cloud: " + name_ + ": cannot open it for gzip reading");
    }
    (void)gzbuffer(g_, 1u << 20);  // before the first read: 1 MiB of compressed input at a time
    // zlib reads a file that is not gzip as it is ("transparent"); the whole read refuses it.
    if (gzdirect(g_) != 0) {
      gzclose(g_);
      throw InputError("load_cloud: " + name_ + " is not valid gzip data (its name ends in .gz)");
    }
  }
  ~GzSource() override { gzclose(g_); }

  std::size_t read(char* out, std::size_t n) override {
    std::size_t done = 0;
    while (done < n) {
      const auto ask = static_cast<unsigned>(std::min<std::size_t>(n - done, std::size_t{1} << 30));
      const int got = gzread(g_, out + done, ask);
      if (got < 0) fail();
      done += static_cast<std::size_t>(got);
      total_ += static_cast<std::uint64_t>(got);
      if (static_cast<unsigned>(got) < ask) {
        int err = Z_OK;
        (void)gzerror(g_, &err);
        if (err != Z_OK) fail();  // Z_BUF_ERROR: the data end inside a member
        break;
      }
    }
    return done;
  }
  void seek(std::uint64_t offset) override {
    const bool ok = offset == 0 ? gzrewind(g_) == 0
                                : offset <= static_cast<std::uint64_t>(LLONG_MAX) &&
                                      gzseek(g_, static_cast<z_off_t>(offset), SEEK_SET) == static_cast<z_off_t>(offset);
    if (!ok) throw InputError("load_cloud: " + name_ + ": cannot go to byte " + std::to_string(offset) + " of its gzip data");
    total_ = offset;
  }

 private:
  [[noreturn]] void fail() {
    int err = Z_OK;
    const char* what = gzerror(g_, &err);
    if (err == Z_BUF_ERROR) {
      throw InputError("load_cloud: gzip data of " + name_ + " is truncated (it ends inside a gzip member, after " +
                       std::to_string(total_) + " bytes decompressed)");
    }
    throw InputError("load_cloud: " + name_ + " is not valid gzip data: " + std::string(what != nullptr ? what : "zlib error"));
  }
  gzFile g_;
  std::uint64_t total_ = 0;  // decompressed bytes read so far (from the last seek)
};

}  // namespace

std::unique_ptr<ByteSource> ByteSource::open(const std::filesystem::path& path, const std::string& name, bool gz) {
  if (!gz) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (f == nullptr) throw InputError("load_cloud: " + name + ": cannot open it: " + std::strerror(errno));
    return std::make_unique<PlainSource>(f, name);
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError("load_cloud: " + name + ": cannot open it: " + std::strerror(errno));
  return std::make_unique<GzSource>(fd, name);
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
