// Stage 1, PCL part: PLY and PCD bodies are parsed by PCL into a pcl::PCLPointCloud2, whose
// fields keep their declared type (float64 stays double), then copied into a Cloud.
//
// PCL's readers take a file name only. Data that exists only in memory (a sanitised PLY, a
// decompressed .gz) is handed over through an anonymous memory file (memfd_create) opened as
// /proc/self/fd/N: nothing touches the disk and the kernel frees it when the descriptor closes,
// even if the process dies. Where memfd_create is unavailable, an unlinked private temporary
// file is used the same way.

#include "hc/common/error.hpp"
#include "hc/pipeline/cloud.hpp"

#include <pcl/PCLPointCloud2.h>
#include <pcl/exceptions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <string>

namespace hc::pipeline::detail {

namespace {

// An in-memory file readable by path; closed (and so freed) on destruction.
class MemoryFile {
 public:
  MemoryFile(const std::string& bytes, const std::string& display_name) {
    fd_ = static_cast<int>(::memfd_create("hapticloud-scan", MFD_CLOEXEC));
    if (fd_ < 0) {
      std::string tmpl = (std::filesystem::temp_directory_path() / "hapticloud-scan-XXXXXX").string();
      fd_ = ::mkstemp(tmpl.data());
      if (fd_ < 0) {
        throw ResourceError("load_cloud: " + display_name + ": cannot create an in-memory or temporary file (" +
                            std::strerror(errno) + ")");
      }
      ::unlink(tmpl.c_str());  // removed now; readable through /proc/self/fd until closed
    }
    std::size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t w = ::write(fd_, bytes.data() + done, bytes.size() - done);
      if (w < 0) {
        if (errno == EINTR) continue;
        const std::string err = std::strerror(errno);
        ::close(fd_);
        throw ResourceError("load_cloud: " + display_name + ": cannot stage " + std::to_string(bytes.size()) +
                            " bytes in memory (" + err + ")");
      }
      done += static_cast<std::size_t>(w);
    }
    path_ = "/proc/self/fd/" + std::to_string(fd_);
  }
  MemoryFile(const MemoryFile&) = delete;
  MemoryFile& operator=(const MemoryFile&) = delete;
  ~MemoryFile() { ::close(fd_); }

  const std::string& path() const { return path_; }

 private:
  int fd_ = -1;
  std::string path_;
};

template <class T>
double read_as_double(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return static_cast<double>(v);
}

double read_field(const std::uint8_t* p, std::uint8_t datatype) {
  switch (datatype) {
    case pcl::PCLPointField::INT8: return read_as_double<std::int8_t>(p);
    case pcl::PCLPointField::UINT8: return read_as_double<std::uint8_t>(p);
    case pcl::PCLPointField::INT16: return read_as_double<std::int16_t>(p);
    case pcl::PCLPointField::UINT16: return read_as_double<std::uint16_t>(p);
    case pcl::PCLPointField::INT32: return read_as_double<std::int32_t>(p);
    case pcl::PCLPointField::UINT32: return read_as_double<std::uint32_t>(p);
    case pcl::PCLPointField::FLOAT32: return read_as_double<float>(p);
    case pcl::PCLPointField::FLOAT64: return read_as_double<double>(p);
    default: return std::numeric_limits<double>::quiet_NaN();
  }
}

// Copies x, y, z of every point of a PCLPointCloud2 into a Cloud, in each field's own type.
Cloud to_cloud(const pcl::PCLPointCloud2& pc, const std::string& display_name) {
  const pcl::PCLPointField* f[3] = {nullptr, nullptr, nullptr};
  const char* names[3] = {"x", "y", "z"};
  for (const auto& field : pc.fields) {
    for (int a = 0; a < 3; ++a) {
      if (field.name == names[a]) f[a] = &field;
    }
  }
  for (int a = 0; a < 3; ++a) {
    if (!f[a]) throw InputError("load_cloud: " + display_name + " has no '" + names[a] + "' field");
    if (f[a]->datatype < pcl::PCLPointField::INT8 || f[a]->datatype > pcl::PCLPointField::FLOAT64) {
      throw InputError("load_cloud: " + display_name + ": field '" + names[a] + "' has an unsupported type");
    }
  }
  const std::size_t n = static_cast<std::size_t>(pc.width) * pc.height;
  if (pc.data.size() < n * pc.point_step) {
    throw InputError("load_cloud: " + display_name + ": PCL returned " + std::to_string(pc.data.size()) +
                     " bytes for " + std::to_string(n) + " points (file truncated?)");
  }
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(n));
  const std::uint8_t* base = pc.data.data();
  const bool all_float = f[0]->datatype == pcl::PCLPointField::FLOAT32 &&
                         f[1]->datatype == pcl::PCLPointField::FLOAT32 &&
                         f[2]->datatype == pcl::PCLPointField::FLOAT32;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint8_t* p = base + i * pc.point_step;
    const Eigen::Index col = static_cast<Eigen::Index>(i);
    if (all_float) {
      cloud.xyz(0, col) = read_as_double<float>(p + f[0]->offset);
      cloud.xyz(1, col) = read_as_double<float>(p + f[1]->offset);
      cloud.xyz(2, col) = read_as_double<float>(p + f[2]->offset);
    } else {
      for (int a = 0; a < 3; ++a) cloud.xyz(a, col) = read_field(p + f[a]->offset, f[a]->datatype);
    }
  }
  return cloud;
}

}  // namespace

Cloud read_ply_body_with_pcl(const std::string& ply_bytes, const std::string& display_name,
                             std::size_t expected_points) {
  const MemoryFile file(ply_bytes, display_name);
  pcl::PCLPointCloud2 pc;
  int rc = -1;
  try {
    pcl::PLYReader reader;
    rc = reader.read(file.path(), pc);
  } catch (const std::exception& e) {
    throw InputError("load_cloud: " + display_name + ": PCL's PLY reader failed: " + e.what());
  }
  if (rc < 0) {
    throw InputError("load_cloud: " + display_name +
                     ": PCL's PLY reader rejected the file (malformed or truncated data; its message is above)");
  }
  Cloud cloud = to_cloud(pc, display_name);
  if (cloud.size() != expected_points) {
    throw InputError("load_cloud: " + display_name + ": read " + std::to_string(cloud.size()) +
                     " points but the header declares " + std::to_string(expected_points));
  }
  return cloud;
}

Cloud read_pcd_with_pcl(const std::string& bytes, const std::filesystem::path& original_path,
                        bool from_memory, const std::string& display_name) {
  pcl::PCLPointCloud2 pc;
  int rc = -1;
  try {
    pcl::PCDReader reader;
    if (from_memory) {
      const MemoryFile file(bytes, display_name);
      rc = reader.read(file.path(), pc);
    } else {
      rc = reader.read(original_path.string(), pc);
    }
  } catch (const std::exception& e) {
    throw InputError("load_cloud: " + display_name + ": PCL's PCD reader failed: " + e.what());
  }
  if (rc < 0) {
    throw InputError("load_cloud: " + display_name +
                     ": PCL's PCD reader rejected the file (malformed header or data; its message is above)");
  }
  return to_cloud(pc, display_name);
}

}  // namespace hc::pipeline::detail
