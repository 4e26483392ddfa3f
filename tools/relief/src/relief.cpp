#include "hc/tools/relief.hpp"
#include "hc/tools/e57_pages.hpp"

#include "hc/common/error.hpp"
#include "hc/common/file_output.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <string>
#include <system_error>
#include <thread>
#include <optional>
#include <vector>

namespace hc::tools {
namespace {

namespace fs = std::filesystem;

// SplitMix64's finaliser (Steele, Lea, Flood, "Fast splittable pseudorandom number generators",
// OOPSLA 2014): a bijective mix of 64 bits, here used as a counter-based generator.
std::uint64_t mix64(std::uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// Uniform in [0, 1): draw j (< 8) of point i.
double uniform(std::uint64_t seed_mixed, std::uint64_t i, unsigned j) {
  return static_cast<double>(mix64(seed_mixed ^ (i * 8U + j)) >> 11) * 0x1p-53;
}

// N(0, 1) from draws j and j + 1 (Box–Muller, the cosine branch).
double gaussian(std::uint64_t seed_mixed, std::uint64_t i, unsigned j) {
  const double u1 = 1.0 - uniform(seed_mixed, i, j);  // (0, 1]
  const double u2 = uniform(seed_mixed, i, j + 1);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * u2);
}

void require(bool ok, const char* field, double value, const char* expected) {
  if (ok) return;
  std::ostringstream msg;
  msg << "relief: " << field << " = " << value << " (expected " << expected << ")";
  throw ConfigError(msg.str());
}

std::uint8_t to_u8(double v) { return static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L)); }

template <typename T>
void put(unsigned char*& p, T v) {
  std::memcpy(p, &v, sizeof v);
  p += sizeof v;
}

constexpr double kLasScale = 1e-4;  // 0.1 mm
constexpr std::size_t kLasHeaderBytes = 227;

std::int32_t las_int(double v_m, const char* axis) {
  const double q = std::round(v_m / kLasScale);
  if (!(q >= std::numeric_limits<std::int32_t>::min() && q <= std::numeric_limits<std::int32_t>::max())) {
    std::ostringstream msg;
    msg << "relief: " << axis << " = " << v_m << " m does not fit LAS's 32-bit integers at " << kLasScale << " m";
    throw ConfigError(msg.str());
  }
  return static_cast<std::int32_t>(q);
}

struct SliceResult {
  std::uint64_t front = 0, back = 0, outliers = 0;
  std::array<std::int32_t, 3> lo{std::numeric_limits<std::int32_t>::max(), std::numeric_limits<std::int32_t>::max(),
                                 std::numeric_limits<std::int32_t>::max()};
  std::array<std::int32_t, 3> hi{std::numeric_limits<std::int32_t>::min(), std::numeric_limits<std::int32_t>::min(),
                                 std::numeric_limits<std::int32_t>::min()};
};

// Encodes the points written at places [first, first + count) into `out` (record_bytes each):
// point first + k, or with `order` (ReliefSpec::sorted) point order[first + k].
void encode_slice(const ReliefSpec& spec, ReliefFormat format, std::uint64_t first, std::size_t count, unsigned char* out,
                  SliceResult& r, const std::uint32_t* order) {
  unsigned char* p = out;
  for (std::size_t k = 0; k < count; ++k) {
    const ReliefPoint pt = relief_point(spec, order != nullptr ? order[first + k] : first + k);
    switch (pt.kind) {
      case ReliefPointKind::kFront: ++r.front; break;
      case ReliefPointKind::kBack: ++r.back; break;
      case ReliefPointKind::kOutlier: ++r.outliers; break;
    }
    if (format == ReliefFormat::kPly) {
      put(p, static_cast<float>(pt.x_m));
      put(p, static_cast<float>(pt.y_m));
      put(p, static_cast<float>(pt.z_m));
      if (spec.rgb) {
        put(p, pt.r);
        put(p, pt.g);
        put(p, pt.b);
      }
      continue;
    }
    const std::array<std::int32_t, 3> q{las_int(pt.x_m, "x"), las_int(pt.y_m, "y"), las_int(pt.z_m, "z")};
    for (int a = 0; a < 3; ++a) {
      r.lo[a] = std::min(r.lo[a], q[a]);
      r.hi[a] = std::max(r.hi[a], q[a]);
      put(p, q[a]);
    }
    put(p, std::uint16_t{0});        // intensity
    put(p, std::uint8_t{0x09});      // return number 1 of 1 (bits 0-2 and 3-5)
    put(p, std::uint8_t{1});         // classification: unclassified
    put(p, std::int8_t{0});          // scan angle rank
    put(p, std::uint8_t{0});         // user data
    put(p, std::uint16_t{1});        // point source ID
    if (spec.rgb) {                  // LAS stores 16-bit colour: scale 8 bit by 257
      put(p, static_cast<std::uint16_t>(pt.r * 257U));
      put(p, static_cast<std::uint16_t>(pt.g * 257U));
      put(p, static_cast<std::uint16_t>(pt.b * 257U));
    }
  }
}

std::string ply_header(const ReliefSpec& spec) {
  std::ostringstream h;
  h << "ply\nformat binary_little_endian 1.0\n";
  h << "comment hc-gen-relief: generated carved wall, units m, seed " << spec.seed
    << (spec.scan_order ? ", scan order" : spec.sorted ? ", sorted into scan order" : "") << "\n";
  h << "element vertex " << spec.points << "\n";
  h << "property float x\nproperty float y\nproperty float z\n";
  if (spec.rgb) h << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  h << "end_header\n";
  return h.str();
}

// LAS 1.2 public header block (ASPRS LAS Specification 1.2, 2008, Table 4: 227 bytes).
std::vector<unsigned char> las_header(const ReliefSpec& spec, const SliceResult& bounds) {
  std::vector<unsigned char> h(kLasHeaderBytes, 0);
  unsigned char* p = h.data();
  std::memcpy(p, "LASF", 4);
  p += 4;
  put(p, std::uint16_t{0});  // file source ID
  put(p, std::uint16_t{0});  // global encoding: GPS week time (no GPS time stored)
  p += 16;                   // project ID (GUID): zero
  put(p, std::uint8_t{1});
  put(p, std::uint8_t{2});
  std::array<char, 32> system{};
  std::array<char, 32> software{};
  std::snprintf(system.data(), system.size(), "%s", "GENERATED");
  std::snprintf(software.data(), software.size(), "%s", "hc-gen-relief");
  std::memcpy(p, system.data(), 32);
  p += 32;
  std::memcpy(p, software.data(), 32);
  p += 32;
  put(p, std::uint16_t{1});     // creation day of year
  put(p, std::uint16_t{2026});  // creation year
  put(p, static_cast<std::uint16_t>(kLasHeaderBytes));
  put(p, static_cast<std::uint32_t>(kLasHeaderBytes));  // offset to point data
  put(p, std::uint32_t{0});                            // number of VLRs
  put(p, static_cast<std::uint8_t>(spec.rgb ? 2 : 0));
  put(p, static_cast<std::uint16_t>(spec.rgb ? 26 : 20));
  put(p, static_cast<std::uint32_t>(spec.points));
  put(p, static_cast<std::uint32_t>(spec.points));  // points by return: all first returns
  for (int i = 0; i < 4; ++i) put(p, std::uint32_t{0});
  for (int a = 0; a < 3; ++a) put(p, kLasScale);
  for (int a = 0; a < 3; ++a) put(p, 0.0);  // offsets
  for (int a = 0; a < 3; ++a) {            // max X, min X, max Y, min Y, max Z, min Z
    put(p, bounds.hi[a] * kLasScale);
    put(p, bounds.lo[a] * kLasScale);
  }
  return h;
}

[[noreturn]] void write_failed(const fs::path& out, int err) {
  throw InputError("relief: cannot write " + out.string() + ": " + std::generic_category().message(err));
}

// ---- E57 (ASTM E2807-11): one data3D scan, written in pages as the points come ----------------

constexpr std::uint64_t kE57Page = kE57PageBytes, kE57Payload = kE57PagePayloadBytes;
constexpr std::size_t kE57Records = 4096;  // records per data packet (at most 18 + 15·4096 bytes < 64 KiB)

// The E57 paged file (E2807 § 7.3): logical bytes in, pages of 1020 of them and their CRC-32C
// (stored big-endian, as the reader checks it) out. Page 0 (the file header and the section
// header, which are known only at the end) is kept and written last.
class E57Pages {
 public:
  E57Pages(std::FILE* f, const fs::path& out) : f_(f), out_(out) { page_.reserve(kE57Page); }
  std::uint64_t logical() const { return logical_; }
  void put(const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    while (n > 0) {
      const std::size_t take = std::min<std::size_t>(n, kE57Payload - page_.size());
      page_.insert(page_.end(), p, p + take);
      p += take;
      n -= take;
      logical_ += take;
      if (page_.size() == kE57Payload) flush();
    }
  }
  void pad_page() {
    while (logical_ % kE57Payload != 0) put("", 1);
  }
  // Writes page 0 with `first` over its first bytes (the headers), at the start of the file.
  void finish(const std::vector<unsigned char>& first) {
    if (!page_.empty()) throw std::logic_error("E57Pages::finish: a page is not full");
    std::memcpy(page0_.data(), first.data(), first.size());
    seal(page0_);
    if (std::fseek(f_, 0, SEEK_SET) != 0 || std::fwrite(page0_.data(), 1, kE57Page, f_) != kE57Page) write_failed(out_, errno);
  }

 private:
  static void seal(std::vector<unsigned char>& page) {
    page.resize(kE57Page);
    e57_seal_page(page.data());
  }
  void flush() {
    if (pages_++ == 0) {
      page0_ = page_;  // written by finish()
      page0_.resize(kE57Page, 0);
      if (std::fwrite(page0_.data(), 1, kE57Page, f_) != kE57Page) write_failed(out_, errno);
      page0_.resize(kE57Payload);
    } else {
      seal(page_);
      if (std::fwrite(page_.data(), 1, kE57Page, f_) != kE57Page) write_failed(out_, errno);
    }
    page_.clear();
  }
  std::FILE* f_;
  fs::path out_;
  std::vector<unsigned char> page_, page0_;
  std::uint64_t logical_ = 0, pages_ = 0;
};

// Writes n records (PLY layout: x y z float [, r g b]) as data packets of kE57Records records:
// one bytestream per field (cartesianX/Y/Z Float single [, colorRed/Green/Blue Integer 0..255]).
// The records of a last, partial packet wait in `pending` for the next call (last: written), so
// that the packets do not depend on the chunks.
void e57_packets(E57Pages& pages, std::vector<unsigned char>& pending, const unsigned char* in, std::size_t in_n, bool rgb, bool last) {
  const std::size_t record = rgb ? 15U : 12U;
  pending.insert(pending.end(), in, in + in_n * record);
  std::size_t n = pending.size() / record;
  if (!last) n -= n % kE57Records;
  const unsigned char* records = pending.data();
  const std::size_t streams = rgb ? 6U : 3U;
  std::vector<unsigned char> packet;
  for (std::size_t i0 = 0; i0 < n; i0 += kE57Records) {
    const std::size_t m = std::min(kE57Records, n - i0);
    packet.clear();
    const auto u16 = [&](std::uint16_t v) {
      packet.push_back(static_cast<unsigned char>(v & 0xFFU));
      packet.push_back(static_cast<unsigned char>(v >> 8));
    };
    packet.push_back(1);  // data packet
    packet.push_back(0);  // flags
    u16(0);               // packet length − 1, set below
    u16(static_cast<std::uint16_t>(streams));
    for (std::size_t a = 0; a < 3; ++a) u16(static_cast<std::uint16_t>(4 * m));
    if (rgb)
      for (std::size_t a = 0; a < 3; ++a) u16(static_cast<std::uint16_t>(m));
    for (std::size_t a = 0; a < 3; ++a)
      for (std::size_t i = i0; i < i0 + m; ++i) packet.insert(packet.end(), records + i * record + 4 * a, records + i * record + 4 * a + 4);
    if (rgb)
      for (std::size_t a = 0; a < 3; ++a)
        for (std::size_t i = i0; i < i0 + m; ++i) packet.push_back(records[i * record + 12 + a]);
    while (packet.size() % 4 != 0) packet.push_back(0);
    const auto l1 = static_cast<std::uint16_t>(packet.size() - 1);
    packet[2] = static_cast<unsigned char>(l1 & 0xFFU);
    packet[3] = static_cast<unsigned char>(l1 >> 8);
    pages.put(packet.data(), packet.size());
  }
  pending.erase(pending.begin(), pending.begin() + static_cast<std::ptrdiff_t>(n * record));
}

std::string e57_xml(const ReliefSpec& spec, std::uint64_t section_physical) {
  std::string x =
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<e57Root type=\"Structure\" xmlns=\"http://www.astm.org/COMMIT/E57/2010-e57-v1.0\">\n"
      "<formatName type=\"String\"><![CDATA[ASTM E57 3D Imaging Data File]]></formatName>\n"
      "<guid type=\"String\"><![CDATA[hc-gen-relief-" + std::to_string(spec.seed) + "-" + std::to_string(spec.points) + "]]></guid>\n"
      "<versionMajor type=\"Integer\">1</versionMajor><versionMinor type=\"Integer\">0</versionMinor>\n"
      "<data3D type=\"Vector\" allowHeterogeneousChildren=\"1\"><vectorChild type=\"Structure\">\n"
      "<guid type=\"String\"><![CDATA[hc-gen-relief-scan]]></guid><name type=\"String\"><![CDATA[generated relief wall]]></name>\n"
      "<points type=\"CompressedVector\" fileOffset=\"" + std::to_string(section_physical) + "\" recordCount=\"" +
      std::to_string(spec.points) + "\"><prototype type=\"Structure\">"
      "<cartesianX type=\"Float\" precision=\"single\"/><cartesianY type=\"Float\" precision=\"single\"/>"
      "<cartesianZ type=\"Float\" precision=\"single\"/>";
  if (spec.rgb) {
    x += "<colorRed type=\"Integer\" minimum=\"0\" maximum=\"255\"/><colorGreen type=\"Integer\" minimum=\"0\" maximum=\"255\"/>"
         "<colorBlue type=\"Integer\" minimum=\"0\" maximum=\"255\"/>";
  }
  x += "</prototype><codecs type=\"Vector\" allowHeterogeneousChildren=\"1\"/></points>\n"
       "</vectorChild></data3D>\n</e57Root>\n";
  return x;
}

struct TempFile {
  fs::path path;
  std::FILE* f = nullptr;
  const ReliefTemporaryFn* told = nullptr;  // told the path, and that it is gone
  ~TempFile() {
    if (f) std::fclose(f);
    if (!path.empty()) {
      std::error_code ec;
      fs::remove(path, ec);
    }
    if (told != nullptr && *told) (*told)(fs::path());
  }
};


}  // namespace

void validate(const ReliefSpec& s) {
  const auto finite = [](double v) { return std::isfinite(v); };
  require(finite(s.width_m) && s.width_m > 0.0, "width_m", s.width_m, "> 0");
  require(finite(s.height_m) && s.height_m > 0.0, "height_m", s.height_m, "> 0");
  require(s.points >= 1, "points", static_cast<double>(s.points), ">= 1");
  require(finite(s.relief_depth_m) && s.relief_depth_m >= 0.0, "relief_depth_m", s.relief_depth_m, ">= 0");
  require(finite(s.course_m) && s.course_m > 0.0, "course_m", s.course_m, "> 0");
  require(finite(s.block_m) && s.block_m > 0.0, "block_m", s.block_m, "> 0");
  require(finite(s.joint_depth_m) && s.joint_depth_m >= 0.0, "joint_depth_m", s.joint_depth_m, ">= 0");
  require(finite(s.joint_half_width_m) && s.joint_half_width_m > 0.0, "joint_half_width_m", s.joint_half_width_m, "> 0");
  require(finite(s.chisel_amplitude_m) && s.chisel_amplitude_m >= 0.0, "chisel_amplitude_m", s.chisel_amplitude_m, ">= 0");
  require(finite(s.chisel_wavelength_m) && s.chisel_wavelength_m > 0.0, "chisel_wavelength_m", s.chisel_wavelength_m, "> 0");
  require(finite(s.noise_sigma_m) && s.noise_sigma_m >= 0.0, "noise_sigma_m", s.noise_sigma_m, ">= 0");
  require(finite(s.thickness_m) && s.thickness_m > 0.0, "thickness_m", s.thickness_m, "> 0");
  require(finite(s.back_fraction) && s.back_fraction >= 0.0 && s.back_fraction <= 1.0, "back_fraction", s.back_fraction,
          "in [0, 1]");
  require(finite(s.outlier_fraction) && s.outlier_fraction >= 0.0 && s.outlier_fraction <= 1.0, "outlier_fraction",
          s.outlier_fraction, "in [0, 1]");
  require(s.back_fraction + s.outlier_fraction <= 1.0, "back_fraction + outlier_fraction",
          s.back_fraction + s.outlier_fraction, "<= 1");
  require(finite(s.outlier_reach_m) && s.outlier_reach_m >= 0.0, "outlier_reach_m", s.outlier_reach_m, ">= 0");
  if (s.sorted) {
    require(!s.scan_order, "sorted", 1.0, "0 with scan_order (two orders asked for)");
    require(s.points < std::numeric_limits<std::uint32_t>::max(), "points", static_cast<double>(s.points), "< 2^32 - 1 with sorted");
  }
}

ScanRaster scan_raster(const ReliefSpec& s) {
  ScanRaster r;
  const double rows = std::round(std::sqrt(static_cast<double>(s.points) * s.height_m / s.width_m));
  // NaN (a spec not validated) and anything below 1 give one row; at most a row a point.
  r.rows = !(rows >= 1.0) ? 1 : rows >= static_cast<double>(s.points) ? std::max<std::uint64_t>(s.points, 1) : static_cast<std::uint64_t>(rows);
  r.cols = s.points / r.rows + (s.points % r.rows != 0 ? 1 : 0);
  return r;
}

double relief_height_m(const ReliefSpec& s, double x, double y) {
  // Joints: rows of blocks from the bottom-left corner, odd courses shifted by half a block.
  const double u = x + 0.5 * s.width_m;
  const double v = y + 0.5 * s.height_m;
  const double course = std::floor(v / s.course_m);
  const double shift = std::fmod(std::fabs(course), 2.0) == 1.0 ? 0.5 * s.block_m : 0.0;
  const double block = std::floor((u - shift) / s.block_m);
  const double dv = v - course * s.course_m;
  const double du = u - shift - block * s.block_m;
  const double d_joint = std::min({dv, s.course_m - dv, du, s.block_m - du});
  const double w = d_joint / s.joint_half_width_m;
  double z = -s.joint_depth_m * std::exp(-w * w);
  // A rosette centred on the block.
  const double cx = du - 0.5 * s.block_m;
  const double cy = dv - 0.5 * s.course_m;
  const double rho = std::hypot(cx, cy);
  const double r_max = 0.35 * std::min(s.block_m, s.course_m) * 1.15;
  if (rho < r_max) {
    const double r = 0.35 * std::min(s.block_m, s.course_m) * (1.0 + 0.15 * std::cos(6.0 * std::atan2(cy, cx)));
    if (rho < r) {
      const double c = std::cos(0.5 * std::numbers::pi * rho / r);
      z += s.relief_depth_m * c * c;
    }
  }
  z += s.chisel_amplitude_m * std::sin(2.0 * std::numbers::pi * (x + 0.5 * y) / s.chisel_wavelength_m);
  return z;
}

ReliefPoint relief_point(const ReliefSpec& s, std::uint64_t i) {
  const std::uint64_t seed = mix64(s.seed);
  ReliefPoint p;
  const double c = uniform(seed, i, 0);
  if (s.scan_order) {
    const ScanRaster ras = scan_raster(s);
    const double col = static_cast<double>(i / ras.rows), row = static_cast<double>(i % ras.rows);
    p.x_m = ((col + uniform(seed, i, 1)) / static_cast<double>(ras.cols) - 0.5) * s.width_m;
    p.y_m = ((row + uniform(seed, i, 2)) / static_cast<double>(ras.rows) - 0.5) * s.height_m;
  } else {
    p.x_m = (uniform(seed, i, 1) - 0.5) * s.width_m;
    p.y_m = (uniform(seed, i, 2) - 0.5) * s.height_m;
  }
  if (c < s.outlier_fraction) {
    p.kind = ReliefPointKind::kOutlier;
    p.z_m = -s.thickness_m + uniform(seed, i, 3) * (s.thickness_m + s.outlier_reach_m);
    const std::uint8_t grey = to_u8(60.0 + 150.0 * uniform(seed, i, 5));
    p.r = p.g = p.b = grey;
    return p;
  }
  const double noise = s.noise_sigma_m > 0.0 ? s.noise_sigma_m * gaussian(seed, i, 3) : 0.0;
  if (c < s.outlier_fraction + s.back_fraction) {
    p.kind = ReliefPointKind::kBack;
    p.z_m = -s.thickness_m + noise;
    p.r = 150, p.g = 122, p.b = 92;
    return p;
  }
  const double h = relief_height_m(s, p.x_m, p.y_m);
  p.z_m = h + noise;
  // Sandstone, lighter where the carving stands out, darker in the joints.
  const double span = s.relief_depth_m + s.joint_depth_m;
  const double shade = span > 0.0 ? 0.7 + 0.3 * std::clamp((h + s.joint_depth_m) / span, 0.0, 1.0) : 1.0;
  p.r = to_u8(214.0 * shade);
  p.g = to_u8(178.0 * shade);
  p.b = to_u8(132.0 * shade);
  return p;
}

namespace {

// ReliefSpec::sorted: the indices of the default order's points in the order written.
std::vector<std::uint32_t> sorted_order(const ReliefSpec& s) {
  // Each point's column of the scan raster from its x (the default order's draw), and its y as
  // a 32-bit fraction of the wall's height: one 64-bit key, sorted with the index as the tie.
  const std::uint64_t seed = mix64(s.seed);
  const ScanRaster ras = scan_raster(s);
  const auto cols = static_cast<double>(ras.cols);
  std::vector<std::uint64_t> key(s.points);
  std::vector<std::uint32_t> order(s.points);
  for (std::uint64_t i = 0; i < s.points; ++i) {
    const double col = std::min(cols - 1.0, std::floor(uniform(seed, i, 1) * cols));
    const double y = std::min(uniform(seed, i, 2) * 0x1p32, 0x1p32 - 1.0);
    key[i] = (static_cast<std::uint64_t>(col) << 32) | static_cast<std::uint64_t>(y);
    order[i] = static_cast<std::uint32_t>(i);
  }
  std::sort(order.begin(), order.end(), [&key](std::uint32_t a, std::uint32_t b) { return key[a] != key[b] ? key[a] < key[b] : a < b; });
  return order;
}

}  // namespace

ReliefWriteStats write_relief(const ReliefSpec& spec, const fs::path& out, std::size_t chunk_points, unsigned threads,
                              const ReliefProgressFn& progress, const ReliefTemporaryFn& temporary) {
  validate(spec);
  require(chunk_points >= 1, "chunk_points", static_cast<double>(chunk_points), ">= 1");
  const std::string ext = out.extension().string();
  ReliefFormat format;
  if (ext == ".ply" || ext == ".PLY") {
    format = ReliefFormat::kPly;
  } else if (ext == ".las" || ext == ".LAS") {
    format = ReliefFormat::kLas;
  } else if (ext == ".e57" || ext == ".E57") {
    format = ReliefFormat::kE57;
    require(spec.points <= std::numeric_limits<std::uint32_t>::max(), "points", static_cast<double>(spec.points),
            "< 2^32 for one E57 scan (hapticloud's reader)");
  } else {
    throw ConfigError("relief: " + out.string() + ": extension '" + ext + "' (expected .ply, .las or .e57)");
  }
  if (format == ReliefFormat::kLas) {
    require(spec.points <= std::numeric_limits<std::uint32_t>::max(), "points", static_cast<double>(spec.points),
            "< 2^32 for LAS 1.2");
    // The box the points can reach, checked once so that no point can fail half-way.
    (void)las_int(0.5 * spec.width_m, "x");
    (void)las_int(0.5 * spec.height_m, "y");
    (void)las_int(-spec.thickness_m - 10.0 * spec.noise_sigma_m, "z");
    (void)las_int(std::max(spec.outlier_reach_m, spec.relief_depth_m + spec.chisel_amplitude_m) + 10.0 * spec.noise_sigma_m, "z");
  }
  std::error_code ec;
  if (fs::exists(fs::symlink_status(out, ec))) {
    throw InputError("relief: " + out.string() + " exists (the generator never replaces a file)");
  }
  const auto t0 = std::chrono::steady_clock::now();
  const std::size_t record = format != ReliefFormat::kLas ? (spec.rgb ? 15U : 12U) : (spec.rgb ? 26U : 20U);
  if (threads == 0) threads = std::max(1U, std::thread::hardware_concurrency());
  chunk_points = static_cast<std::size_t>(std::min<std::uint64_t>(chunk_points, spec.points));

  TempFile tmp;
  tmp.path = create_temporary_beside(out);
  if (temporary) {
    tmp.told = &temporary;
    temporary(tmp.path);
  }
  tmp.f = std::fopen(tmp.path.c_str(), "wb");
  if (!tmp.f) write_failed(out, errno);

  const std::string ply = format == ReliefFormat::kPly ? ply_header(spec) : std::string();
  const std::size_t header_bytes = format == ReliefFormat::kPly ? ply.size() : kLasHeaderBytes;
  // E57: the file header (48 bytes), the binary section's header (32), then its data packets.
  std::optional<E57Pages> e57;
  std::vector<unsigned char> e57_pending;  // records of a partial packet (at most 4095)
  if (format == ReliefFormat::kE57) {
    e57.emplace(tmp.f, out);
    const std::vector<unsigned char> headers(80, 0);  // written at the end (E57Pages::finish)
    e57->put(headers.data(), headers.size());
  } else if (format == ReliefFormat::kPly) {
    if (std::fwrite(ply.data(), 1, ply.size(), tmp.f) != ply.size()) write_failed(out, errno);
  } else {
    const std::vector<unsigned char> placeholder(kLasHeaderBytes, 0);
    if (std::fwrite(placeholder.data(), 1, placeholder.size(), tmp.f) != placeholder.size()) write_failed(out, errno);
  }

  ReliefWriteStats stats;
  const std::vector<std::uint32_t> order = spec.sorted ? sorted_order(spec) : std::vector<std::uint32_t>();
  std::vector<unsigned char> buffer(chunk_points * record);
  stats.buffer_bytes = buffer.size();
  SliceResult total;
  for (std::uint64_t first = 0; first < spec.points; first += chunk_points) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(chunk_points, spec.points - first));
    const unsigned t_count = static_cast<unsigned>(std::min<std::size_t>(threads, std::max<std::size_t>(1, n / 4096)));
    std::vector<SliceResult> parts(t_count);
    std::vector<std::jthread> workers;  // joined on any exit, so a failed spawn cannot terminate
    std::vector<std::exception_ptr> errors(t_count);
    const std::size_t per = (n + t_count - 1) / t_count;
    for (unsigned t = 0; t < t_count; ++t) {
      const std::size_t a = std::min(n, t * per), b = std::min(n, a + per);
      auto body = [&, t, a, b] {
        try {
          encode_slice(spec, format == ReliefFormat::kE57 ? ReliefFormat::kPly : format, first + a, b - a, buffer.data() + a * record,
                       parts[t], order.empty() ? nullptr : order.data());
        } catch (...) {
          errors[t] = std::current_exception();
        }
      };
      if (t + 1 == t_count) {
        body();
      } else {
        workers.emplace_back(body);
      }
    }
    for (std::jthread& w : workers) w.join();
    for (const std::exception_ptr& e : errors)
      if (e) std::rethrow_exception(e);
    for (const SliceResult& r : parts) {
      total.front += r.front;
      total.back += r.back;
      total.outliers += r.outliers;
      for (int a = 0; a < 3; ++a) {
        total.lo[a] = std::min(total.lo[a], r.lo[a]);
        total.hi[a] = std::max(total.hi[a], r.hi[a]);
      }
    }
    if (e57) {
      e57_packets(*e57, e57_pending, buffer.data(), n, spec.rgb, first + n == spec.points);
    } else if (std::fwrite(buffer.data(), record, n, tmp.f) != n) {
      write_failed(out, errno);
    }
    if (progress) progress(first + n, spec.points);
  }
  std::uint64_t e57_bytes = 0;
  if (e57) {
    // The section ends with its last packet; the XML follows (E2807 § 8), then the last page's
    // padding; then page 0 gets the two headers.
    const std::uint64_t section_logical_bytes = e57->logical() - 48;
    const std::string xml = e57_xml(spec, 48);
    while (e57->logical() % 4 != 0) e57->put("", 1);
    const std::uint64_t xml_logical = e57->logical();
    e57->put(xml.data(), xml.size());
    e57->pad_page();
    const std::uint64_t physical_bytes = e57->logical() / kE57Payload * kE57Page;
    std::vector<unsigned char> h(80, 0);
    unsigned char* p = h.data();
    std::memcpy(p, "ASTM-E57", 8);
    p += 8;
    put(p, std::uint32_t{1});  // versionMajor
    put(p, std::uint32_t{0});  // versionMinor
    put(p, physical_bytes);    // filePhysicalLength
    put(p, e57_physical(xml_logical));
    put(p, static_cast<std::uint64_t>(xml.size()));
    put(p, kE57Page);
    put(p, std::uint8_t{1});  // binary section header (§ 9.1): CompressedVector
    p += 7;
    put(p, section_logical_bytes);
    put(p, e57_physical(80));      // dataPhysicalOffset: the first packet
    put(p, std::uint64_t{0});      // indexPhysicalOffset: no index packets
    e57->finish(h);
    e57_bytes = physical_bytes;
  }
  if (format == ReliefFormat::kLas) {
    const std::vector<unsigned char> header = las_header(spec, total);
    if (std::fseek(tmp.f, 0, SEEK_SET) != 0 || std::fwrite(header.data(), 1, header.size(), tmp.f) != header.size()) {
      write_failed(out, errno);
    }
  }
  if (std::fflush(tmp.f) != 0) write_failed(out, errno);
  const int closed = std::fclose(tmp.f);
  tmp.f = nullptr;
  if (closed != 0) write_failed(out, errno);
  if (!link_into_place(tmp.path, out)) {
    const int err = errno;
    if (err == EEXIST) throw InputError("relief: " + out.string() + " appeared while it was written; it was not replaced");
    write_failed(out, err);
  }
  tmp.path.clear();
  stats.points = spec.points;
  stats.front = total.front;
  stats.back = total.back;
  stats.outliers = total.outliers;
  stats.bytes = e57 ? e57_bytes : header_bytes + spec.points * record;
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

std::uint32_t e57_crc32c(const unsigned char* p, std::size_t n) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1U) ? (c >> 1) ^ 0x82F63B78U : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  std::uint32_t c = 0xFFFFFFFFU;
  for (std::size_t i = 0; i < n; ++i) c = table[(c ^ p[i]) & 0xFFU] ^ (c >> 8);
  return ~c;
}

void e57_seal_page(unsigned char* page) {
  const std::uint32_t c = e57_crc32c(page, kE57PagePayloadBytes);
  for (std::size_t k = 0; k < 4; ++k) page[kE57PagePayloadBytes + k] = static_cast<unsigned char>(c >> (24 - 8 * k));
}

std::string e57_pages(std::string_view logical) {
  if (logical.size() % kE57PagePayloadBytes != 0) {
    throw std::invalid_argument("e57_pages: a logical stream of " + std::to_string(logical.size()) +
                                " bytes (expected a multiple of 1020: pad it to whole pages)");
  }
  std::string file(logical.size() / kE57PagePayloadBytes * kE57PageBytes, '\0');
  for (std::size_t at = 0, out = 0; at < logical.size(); at += kE57PagePayloadBytes, out += kE57PageBytes) {
    std::memcpy(file.data() + out, logical.data() + at, kE57PagePayloadBytes);
    e57_seal_page(reinterpret_cast<unsigned char*>(file.data() + out));
  }
  return file;
}

}  // namespace hc::tools
