// PCD files written by PCL itself (pcl_pcd_writer.hpp).

#include "pcl_pcd_writer.hpp"

#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>

#include <cstring>
#include <stdexcept>

namespace hc::test {

namespace {

// pcl::PCLPointField's datatype for a PCD TYPE and SIZE.
std::uint8_t datatype_of(const PcdField& f) {
  using T = pcl::PCLPointField;
  if (f.type == 'F') return f.size == 8 ? T::FLOAT64 : T::FLOAT32;
  const bool s = f.type == 'I';
  switch (f.size) {
    case 1: return s ? T::INT8 : T::UINT8;
    case 2: return s ? T::INT16 : T::UINT16;
    case 4: return s ? T::INT32 : T::UINT32;
    default: throw std::runtime_error("write_pcl_compressed_pcd: no PCL type for " + f.name);
  }
}

}  // namespace

void write_pcl_compressed_pcd(const std::filesystem::path& p, const std::vector<PcdField>& fields, const std::string& records,
                              std::uint32_t width, std::uint32_t height) {
  pcl::PCLPointCloud2 cloud;
  std::uint32_t step = 0;
  for (const PcdField& f : fields) {
    pcl::PCLPointField pf;
    pf.name = f.name;
    pf.offset = step;
    pf.datatype = datatype_of(f);
    pf.count = static_cast<std::uint32_t>(f.count);
    cloud.fields.push_back(pf);
    step += static_cast<std::uint32_t>(f.size * f.count);
  }
  cloud.width = width;
  cloud.height = height;
  cloud.point_step = step;
  cloud.row_step = step * width;
  cloud.is_dense = false;
  if (records.size() != static_cast<std::size_t>(step) * width * height) {
    throw std::runtime_error("write_pcl_compressed_pcd: " + std::to_string(records.size()) + " bytes are not " +
                             std::to_string(width * height) + " records of " + std::to_string(step));
  }
  cloud.data.resize(records.size());
  std::memcpy(cloud.data.data(), records.data(), records.size());
  pcl::PCDWriter writer;
  if (writer.writeBinaryCompressed(p.string(), cloud) != 0) throw std::runtime_error("PCL could not write " + p.string());
}

}  // namespace hc::test
