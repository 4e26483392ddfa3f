#include "hc/common/file_output.hpp"

#include "hc/common/error.hpp"

#include <cerrno>
#include <cstring>
#include <fstream>
#include <string>
#include <system_error>

#include <sys/stat.h>
#include <unistd.h>

namespace hc {

namespace {

// The process's umask from /proc/self/status ("Umask:\t0022", Linux 4.7+); 022 if unreadable.
mode_t current_umask() {
  std::ifstream in("/proc/self/status");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("Umask:", 0) == 0) return static_cast<mode_t>(std::stoul(line.substr(6), nullptr, 8));
  }
  return 022;
}

}  // namespace

std::filesystem::path create_temporary_beside(const std::filesystem::path& file) {
  std::string name = (file.parent_path() / (file.filename().string() + ".part-XXXXXX")).string();
  const int fd = ::mkstemp(name.data());
  if (fd < 0) throw InputError("cannot create a temporary file beside " + file.string() + ": " + std::strerror(errno));
  // Permissions of a new file under the umask (mkstemp made it 0600). The umask is read from
  // /proc, not by umask(2)'s set-and-restore, which would race with other threads' files.
  (void)::fchmod(fd, static_cast<mode_t>(0666 & ~current_umask()));
  ::close(fd);
  return std::filesystem::path(name);
}

bool link_into_place(const std::filesystem::path& tmp, const std::filesystem::path& target) {
  if (::link(tmp.c_str(), target.c_str()) != 0) return false;
  std::error_code ec;
  std::filesystem::remove(tmp, ec);
  return true;
}

}  // namespace hc
