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

// The PCLPointCloud2 of width × height records of `fields`.
pcl::PCLPointCloud2 cloud_of(const std::vector<PcdField>& fields, const std::string& records, std::uint32_t width, std::uint32_t height) {
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
  return cloud;
}

}  // namespace

void write_pcl_compressed_pcd(const std::filesystem::path& p, const std::vector<PcdField>& fields, const std::string& records,
                              std::uint32_t width, std::uint32_t height, bool compressed) {
  const pcl::PCLPointCloud2 cloud = cloud_of(fields, records, width, height);
  pcl::PCDWriter writer;
  if ((compressed ? writer.writeBinaryCompressed(p.string(), cloud) : writer.writeBinary(p.string(), cloud)) != 0) {
    throw std::runtime_error("PCL could not write " + p.string());
  }
}

void write_pcl_ascii_pcd(const std::filesystem::path& p, const std::vector<PcdField>& fields, const std::string& records,
                         std::uint32_t width, std::uint32_t height, int precision) {
  const pcl::PCLPointCloud2 cloud = cloud_of(fields, records, width, height);
  pcl::PCDWriter writer;
  if (writer.writeASCII(p.string(), cloud, Eigen::Vector4f::Zero(), Eigen::Quaternionf::Identity(), precision) != 0) {
    throw std::runtime_error("PCL could not write " + p.string());
  }
}

void read_pcl_pcd(const std::filesystem::path& p, std::vector<double>& xyz, std::vector<std::uint8_t>& rgb,
                  std::vector<float>& intensity) {
  pcl::PCLPointCloud2 cloud;
  pcl::PCDReader reader;
  if (reader.read(p.string(), cloud) < 0) throw std::runtime_error("PCL could not read " + p.string());
  const auto field = [&](const std::string& name) -> const pcl::PCLPointField* {
    for (const auto& f : cloud.fields)
      if (f.name == name) return &f;
    return nullptr;
  };
  const auto value = [](const pcl::PCLPointField& f, const std::uint8_t* at) -> double {
    using T = pcl::PCLPointField;
    const auto get = [at](auto v) {
      std::memcpy(&v, at, sizeof v);
      return static_cast<double>(v);
    };
    switch (f.datatype) {
      case T::INT8: return get(std::int8_t{});
      case T::UINT8: return get(std::uint8_t{});
      case T::INT16: return get(std::int16_t{});
      case T::UINT16: return get(std::uint16_t{});
      case T::INT32: return get(std::int32_t{});
      case T::UINT32: return get(std::uint32_t{});
      case T::FLOAT32: return get(float{});
      case T::INT64: return get(std::int64_t{});
      case T::UINT64: return get(std::uint64_t{});
      default: return get(double{});
    }
  };
  const pcl::PCLPointField* axis[3] = {field("x"), field("y"), field("z")};
  for (const auto* a : axis)
    if (a == nullptr) throw std::runtime_error("read_pcl_pcd: no x, y or z in " + p.string());
  // A packed colour is 4 bytes (PCL's pcl::RGB): a field named rgb or rgba of another size is none.
  const auto packed = [](const pcl::PCLPointField* f) {
    using T = pcl::PCLPointField;
    return f != nullptr && (f->datatype == T::UINT32 || f->datatype == T::INT32 || f->datatype == T::FLOAT32) ? f : nullptr;
  };
  const pcl::PCLPointField* colour = packed(field("rgb")) != nullptr ? packed(field("rgb")) : packed(field("rgba"));
  const std::size_t n = static_cast<std::size_t>(cloud.width) * cloud.height;
  xyz.assign(3 * n, 0.0);
  rgb.assign(colour != nullptr ? 3 * n : 0, 0);
  const pcl::PCLPointField* level = field("intensity");
  intensity.assign(level != nullptr ? n : 0, 0.0f);
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint8_t* rec = cloud.data.data() + i * cloud.point_step;
    for (std::size_t a = 0; a < 3; ++a) xyz[3 * i + a] = value(*axis[a], rec + axis[a]->offset);
    if (level != nullptr) intensity[i] = static_cast<float>(value(*level, rec + level->offset));
    if (colour != nullptr) {
      std::uint32_t v = 0;
      std::memcpy(&v, rec + colour->offset, 4);
      rgb[3 * i] = static_cast<std::uint8_t>(v >> 16);
      rgb[3 * i + 1] = static_cast<std::uint8_t>(v >> 8);
      rgb[3 * i + 2] = static_cast<std::uint8_t>(v);
    }
  }
}

}  // namespace hc::test
