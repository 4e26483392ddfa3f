// E57 reader tests (ASTM E2807) on the shared scanner samples, a synthetic two-scan file written
// here, and bad input. Every expected value is obtained independently of the reader: the XML is
// located from the header fields and cut out of the pages with a loop of this file, record counts,
// bounds and limits are searched in that text, and points are decoded by hand from the binary
// sections with a naive bit-at-a-time extractor.

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/point_stream.hpp"
#include "test_paths.hpp"
#include "file_bytes.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <fstream>
#include <random>
#include <string>
#include <vector>

namespace hp = hc::pipeline;
namespace fs = std::filesystem;

namespace {

using hc::test::read_bytes;
using hc::test::write_bytes;

fs::path sample(const std::string& name) { return hc::test::scan_path("scanner_samples/e57/" + name); }

template <class T>
T get(const std::string& s, std::size_t at) {
  T v;
  std::memcpy(&v, s.data() + at, sizeof(T));
  return v;
}

// ---- oracle: pages stripped, XML text, naive string search --------------------------------------

struct Oracle {
  std::string logical;  // file with the 4 CRC bytes of every 1024-byte page removed
  std::string xml;
  static std::size_t logical_of(std::size_t phys) { return phys / 1024 * 1020 + phys % 1024; }
};

Oracle oracle(const fs::path& p) {
  const std::string bytes = read_bytes(p);
  Oracle o;
  for (std::size_t at = 0; at + 1024 <= bytes.size(); at += 1024) o.logical += bytes.substr(at, 1020);
  const auto xml_off = get<std::uint64_t>(bytes, 24);
  const auto xml_len = get<std::uint64_t>(bytes, 32);
  o.xml = o.logical.substr(Oracle::logical_of(xml_off), xml_len);
  return o;
}

// Values of attribute `attr` of every element `<tag ` in document order.
std::vector<std::string> attrs(const std::string& xml, const std::string& tag, const std::string& attr) {
  std::vector<std::string> out;
  for (std::size_t at = xml.find("<" + tag + " "); at != std::string::npos; at = xml.find("<" + tag + " ", at + 1)) {
    const std::size_t close = xml.find('>', at);
    const std::size_t a = xml.find(" " + attr + "=\"", at);
    if (a == std::string::npos || a > close) {
      out.emplace_back();
      continue;
    }
    const std::size_t v = a + attr.size() + 3;
    out.push_back(xml.substr(v, xml.find('"', v) - v));
  }
  return out;
}

// Text of the k-th element `<tag ...>text</tag>` (a self-closing element is "0", the E57 default).
double elem(const std::string& xml, const std::string& tag, std::size_t k = 0) {
  std::size_t at = xml.find("<" + tag + " ");
  for (std::size_t i = 0; i < k && at != std::string::npos; ++i) at = xml.find("<" + tag + " ", at + 1);
  if (at == std::string::npos) {
    ADD_FAILURE() << "no <" << tag << "> number " << k;
    return NAN;
  }
  const std::size_t close = xml.find('>', at);
  if (xml[close - 1] == '/') return 0.0;
  return std::stod(xml.substr(close + 1, xml.find('<', close) - close - 1));
}

std::size_t total_records(const Oracle& o) {
  std::size_t n = 0;
  const auto counts = attrs(o.xml, "points", "recordCount");
  for (const auto& c : counts) n += std::stoull(c);
  return n;
}

// The bytestreams of the CompressedVector at physical offset `file_offset`, packets walked by hand.
std::vector<std::string> streams_by_hand(const Oracle& o, std::size_t file_offset) {
  const std::size_t section = Oracle::logical_of(file_offset);
  const auto length = get<std::uint64_t>(o.logical, section + 8);
  std::size_t at = Oracle::logical_of(get<std::uint64_t>(o.logical, section + 16));
  std::vector<std::string> s;
  while (at < section + length) {
    const std::size_t len = get<std::uint16_t>(o.logical, at + 2) + 1U;
    if (o.logical[at] == 1) {
      const std::size_t n = get<std::uint16_t>(o.logical, at + 4);
      s.resize(n);
      std::size_t b = at + 6 + 2 * n;
      for (std::size_t k = 0; k < n; ++k) {
        const std::size_t bl = get<std::uint16_t>(o.logical, at + 6 + 2 * k);
        s[k] += o.logical.substr(b, bl);
        b += bl;
      }
    }
    at += len;
  }
  return s;
}

// Value i of a bit-packed stream of `bits`-bit integers, one bit at a time, LSB first.
std::uint64_t bits_at(const std::string& s, std::size_t i, unsigned bits) {
  std::uint64_t v = 0;
  for (unsigned b = 0; b < bits; ++b) {
    const std::size_t bit = i * bits + b;
    if ((static_cast<unsigned char>(s[bit / 8]) >> (bit % 8)) & 1U) v |= std::uint64_t{1} << b;
  }
  return v;
}

struct Box {
  Eigen::Vector3d lo, hi;
};
Box box(const hp::Cloud& c) { return {c.xyz.rowwise().minCoeff(), c.xyz.rowwise().maxCoeff()}; }

// cartesianBounds (scan k) from the XML.
Box xml_bounds(const Oracle& o, std::size_t k = 0) {
  return {{elem(o.xml, "xMinimum", k), elem(o.xml, "yMinimum", k), elem(o.xml, "zMinimum", k)},
          {elem(o.xml, "xMaximum", k), elem(o.xml, "yMaximum", k), elem(o.xml, "zMaximum", k)}};
}

void expect_box(const Box& got, const Box& want, double tol) {
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(got.lo[a], want.lo[a], tol) << "axis " << a;
    EXPECT_NEAR(got.hi[a], want.hi[a], tol) << "axis " << a;
  }
}

bool notes_mention(const hp::StageReport& r, const std::string& what) {
  return std::any_of(r.notes.begin(), r.notes.end(), [&](const std::string& n) { return n.find(what) != std::string::npos; });
}

std::string load_error(const fs::path& p) {
  try {
    hp::load_cloud(p);
  } catch (const hc::InputError& e) {
    return e.what();
  }
  return "(no error)";
}

// ---- a small E57 writer: uncompressed double coordinates, one page-aligned layout ----------------

std::uint32_t crc32c_bitwise(const char* p, std::size_t n) {
  std::uint32_t c = 0xFFFFFFFFU;
  for (std::size_t i = 0; i < n; ++i) {
    c ^= static_cast<unsigned char>(p[i]);
    for (int k = 0; k < 8; ++k) c = (c & 1U) ? (c >> 1) ^ 0x82F63B78U : c >> 1;
  }
  return ~c;
}

template <class T>
void put(std::string& s, T v) {
  s.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

std::size_t physical_of(std::size_t logical) { return logical / 1020 * 1024 + logical % 1020; }

struct SynthScan {
  Eigen::Matrix3Xd local;  // points in the scan's own frame
  double q[4];             // w x y z
  Eigen::Vector3d t;
  std::size_t claimed = 0;  // recordCount written to the XML (0: the real count)
  std::vector<std::uint8_t> state = {};  // cartesianInvalidState per point (8-bit Integer); empty: no field
  std::vector<double> intensity = {};     // intensity per point (Float, no limits); empty: no field
  std::uint8_t trailing_packet_type = 0;  // a 16-byte packet of this type after the data (0: none)
};

// Writes an E57 file: header, one binary section per scan (packets of at most 700 records, with an
// empty packet after the first one), then the XML. `xml_override` replaces the XML text.
std::string write_e57(const std::vector<SynthScan>& scans, const std::string& xml_override = "") {
  std::string log(48, '\0');
  std::vector<std::size_t> offsets;
  for (const auto& sc : scans) {
    while (log.size() % 4) log += '\0';
    const std::size_t start = log.size();
    offsets.push_back(physical_of(start));
    std::string body;
    const auto n = static_cast<std::size_t>(sc.local.cols());
    bool first = true;
    for (std::size_t i0 = 0; i0 < n; i0 += 700) {
      const std::size_t m = std::min<std::size_t>(700, n - i0);
      std::string pk;
      put<std::uint8_t>(pk, 1);
      put<std::uint8_t>(pk, 0);
      put<std::uint16_t>(pk, 0);  // length − 1, patched below
      const bool with_state = !sc.state.empty(), with_intensity = !sc.intensity.empty();
      put<std::uint16_t>(pk, static_cast<std::uint16_t>(3 + (with_state ? 1 : 0) + (with_intensity ? 1 : 0)));
      for (int a = 0; a < 3; ++a) put<std::uint16_t>(pk, static_cast<std::uint16_t>(8 * m));
      if (with_state) put<std::uint16_t>(pk, static_cast<std::uint16_t>(m));
      if (with_intensity) put<std::uint16_t>(pk, static_cast<std::uint16_t>(8 * m));
      for (int a = 0; a < 3; ++a)
        for (std::size_t i = i0; i < i0 + m; ++i) put<double>(pk, sc.local(a, static_cast<Eigen::Index>(i)));
      if (with_state)
        for (std::size_t i = i0; i < i0 + m; ++i) put<std::uint8_t>(pk, sc.state[i]);
      if (with_intensity)
        for (std::size_t i = i0; i < i0 + m; ++i) put<double>(pk, sc.intensity[i]);
      while (pk.size() % 4) pk += '\0';
      const auto l1 = static_cast<std::uint16_t>(pk.size() - 1);
      std::memcpy(pk.data() + 2, &l1, 2);
      body += pk;
      if (first) {  // an empty packet (type 2), which a reader skips
        std::string e;
        put<std::uint8_t>(e, 2);
        put<std::uint8_t>(e, 0);
        put<std::uint16_t>(e, 15);
        e.append(12, '\0');
        body += e;
        first = false;
      }
    }
    if (sc.trailing_packet_type != 0) {
      std::string e;
      put<std::uint8_t>(e, sc.trailing_packet_type);
      put<std::uint8_t>(e, 0);
      put<std::uint16_t>(e, 15);
      e.append(12, '\0');
      body += e;
    }
    std::string hdr;
    put<std::uint8_t>(hdr, 1);
    hdr.append(7, '\0');
    put<std::uint64_t>(hdr, 32 + body.size());
    put<std::uint64_t>(hdr, physical_of(start + 32));
    put<std::uint64_t>(hdr, 0);
    log += hdr + body;
  }
  std::string xml = xml_override;
  if (xml.empty()) {
    xml = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<e57Root type=\"Structure\" "
          "xmlns=\"http://www.astm.org/COMMIT/E57/2010-e57-v1.0\">\n"
          "<formatName type=\"String\"><![CDATA[ASTM E57 3D Imaging Data File]]></formatName>\n"
          "<data3D type=\"Vector\" allowHeterogeneousChildren=\"1\">\n";
    char buf[1024];
    for (std::size_t k = 0; k < scans.size(); ++k) {
      const auto& sc = scans[k];
      std::snprintf(buf, sizeof buf,
                    "<vectorChild type=\"Structure\"><name type=\"String\"><![CDATA[synthetic %zu]]></name>"
                    "<pose type=\"Structure\"><rotation type=\"Structure\"><w type=\"Float\">%.17g</w>"
                    "<x type=\"Float\">%.17g</x><y type=\"Float\">%.17g</y><z type=\"Float\">%.17g</z></rotation>"
                    "<translation type=\"Structure\"><x type=\"Float\">%.17g</x><y type=\"Float\">%.17g</y>"
                    "<z type=\"Float\">%.17g</z></translation></pose>\n",
                    k, sc.q[0], sc.q[1], sc.q[2], sc.q[3], sc.t.x(), sc.t.y(), sc.t.z());
      xml += buf;
      std::snprintf(buf, sizeof buf,
                    "<points type=\"CompressedVector\" fileOffset=\"%zu\" recordCount=\"%zu\">"
                    "<prototype type=\"Structure\"><cartesianX type=\"Float\"/><cartesianY type=\"Float\"/>"
                    "<cartesianZ type=\"Float\"/>%s</prototype><codecs type=\"Vector\" allowHeterogeneousChildren=\"1\"/>"
                    "</points></vectorChild>\n",
                    offsets[k], sc.claimed ? sc.claimed : static_cast<std::size_t>(sc.local.cols()),
                    (std::string(sc.state.empty() ? "" : "<cartesianInvalidState type=\"Integer\" minimum=\"0\" maximum=\"255\"/>") +
                     (sc.intensity.empty() ? "" : "<intensity type=\"Float\"/>")).c_str());
      xml += buf;
    }
    xml += "</data3D>\n</e57Root>\n";
  }
  while (log.size() % 4) log += '\0';
  const std::size_t xml_log = log.size();
  log += xml;
  while (log.size() % 1020) log += '\0';
  // header
  std::string h = "ASTM-E57";
  put<std::uint32_t>(h, 1);
  put<std::uint32_t>(h, 0);
  put<std::uint64_t>(h, log.size() / 1020 * 1024);
  put<std::uint64_t>(h, physical_of(xml_log));
  put<std::uint64_t>(h, xml.size());
  put<std::uint64_t>(h, 1024);
  log.replace(0, 48, h);
  std::string file;
  for (std::size_t at = 0; at < log.size(); at += 1020) {
    file += log.substr(at, 1020);
    const std::uint32_t c = crc32c_bitwise(log.data() + at, 1020);
    for (int sh = 24; sh >= 0; sh -= 8) file += static_cast<char>((c >> sh) & 0xFFU);  // big-endian
  }
  return file;
}

}  // namespace

// ---- the shared samples ----------------------------------------------------------------------

TEST(E57Reader, BunnyDoubleMatchesHandDecodedPointsAndXmlBounds) {
  const fs::path p = sample("libe57-bunnyDouble.e57");
  const Oracle o = oracle(p);
  const auto r = hp::load_cloud(p);
  const hp::Cloud& c = r.value;
  // Hand decoding: section header at fileOffset, data packet offset at +16; a data packet is
  // type(1) flags(1) length−1(2) count(2) then count buffer lengths, then the buffers.
  const std::size_t fo = std::stoull(attrs(o.xml, "points", "fileOffset").at(0));
  const std::size_t data = Oracle::logical_of(get<std::uint64_t>(o.logical, Oracle::logical_of(fo) + 16));
  ASSERT_EQ(o.logical[data], 1) << "first packet is a data packet";
  ASSERT_EQ(get<std::uint16_t>(o.logical, data + 4), 4U) << "x, y, z, invalid state";
  const std::size_t lx = get<std::uint16_t>(o.logical, data + 6), ly = get<std::uint16_t>(o.logical, data + 8);
  const std::size_t bx = data + 6 + 2 * 4;
  const Eigen::Vector3d first(get<double>(o.logical, bx), get<double>(o.logical, bx + lx),
                              get<double>(o.logical, bx + lx + ly));
  const auto s = streams_by_hand(o, fo);
  ASSERT_EQ(s.size(), 4U);
  const std::size_t n = std::stoull(attrs(o.xml, "points", "recordCount").at(0));
  ASSERT_EQ(n, 30571U);
  ASSERT_GE(s[0].size(), 8 * n);
  std::size_t valid = 0;
  for (std::size_t i = 0; i < n; ++i) valid += bits_at(s[3], i, 1) == 0;
  ASSERT_EQ(c.size(), valid);
  ASSERT_EQ(bits_at(s[3], 0, 1), 0U);
  ASSERT_EQ(bits_at(s[3], n - 1, 1), 0U);
  EXPECT_EQ(c.xyz.col(0), first);
  const Eigen::Vector3d last(get<double>(s[0], 8 * (n - 1)), get<double>(s[1], 8 * (n - 1)), get<double>(s[2], 8 * (n - 1)));
  EXPECT_EQ(c.xyz.col(static_cast<Eigen::Index>(c.size() - 1)), last);
  expect_box(box(c), xml_bounds(o), 1e-12);
  EXPECT_FALSE(c.has_intensity());
  EXPECT_FALSE(c.has_rgb());
  EXPECT_FALSE(c.has_scan_id());
}

TEST(E57Reader, BunnyInt32ScaledIntegersMatchTheDoubleTwin) {
  const auto d = hp::load_cloud(sample("libe57-bunnyDouble.e57")).value;
  const auto i = hp::load_cloud(sample("libe57-bunnyInt32.e57")).value;
  ASSERT_EQ(i.size(), d.size());
  // scale 1e-6 (XML): every coordinate within half a step of the double file's.
  const double scale = std::stod(attrs(oracle(sample("libe57-bunnyInt32.e57")).xml, "cartesianX", "scale").at(0));
  EXPECT_LE((i.xyz - d.xyz).cwiseAbs().maxCoeff(), 0.5 * scale + 1e-12);
  expect_box(box(i), xml_bounds(oracle(sample("libe57-bunnyInt32.e57"))), scale);
}

TEST(E57Reader, PumpBitPackedFieldsMatchHandDecoding) {
  const fs::path p = sample("pye57-pumpAVisualReferenceImage.e57");
  const Oracle o = oracle(p);
  const auto r = hp::load_cloud(p);
  const hp::Cloud& c = r.value;
  const std::size_t n = std::stoull(attrs(o.xml, "points", "recordCount").at(0));
  ASSERT_EQ(n, 155201U);
  // Prototype (XML): x y z ScaledInteger 24 bit, intensity 15 bit, r g b 8 bit, row 11 bit,
  // column 9 bit, invalid state 2 bit; widths = ceil(log2(max − min + 1)).
  const double sxyz = std::stod(attrs(o.xml, "cartesianX", "scale").at(0));
  const double si = std::stod(attrs(o.xml, "intensity", "scale").at(0));
  const auto s = streams_by_hand(o, std::stoull(attrs(o.xml, "points", "fileOffset").at(0)));
  ASSERT_EQ(s.size(), 10U);
  std::vector<std::size_t> valid;
  for (std::size_t k = 0; k < n; ++k)
    if (bits_at(s[9], k, 2) == 0) valid.push_back(k);
  ASSERT_EQ(c.size(), valid.size());
  ASSERT_TRUE(c.has_intensity());
  ASSERT_TRUE(c.has_rgb());
  ASSERT_TRUE(c.has_grid_index());
  const double imax = elem(o.xml, "intensityMaximum") * si;  // ScaledInteger limit: raw · scale
  for (const std::size_t j : {std::size_t{0}, std::size_t{1}, valid.size() / 2, valid.size() - 1}) {
    const std::size_t k = valid[j];
    for (int a = 0; a < 3; ++a) {
      const double v = (static_cast<double>(bits_at(s[static_cast<std::size_t>(a)], k, 24)) - 8388608.0) * sxyz;
      EXPECT_DOUBLE_EQ(c.xyz(a, static_cast<Eigen::Index>(j)), v) << "record " << k << " axis " << a;
    }
    EXPECT_NEAR(c.intensity[j], static_cast<double>(bits_at(s[3], k, 15)) * si / imax, 1e-6);
    for (int ch = 0; ch < 3; ++ch)
      EXPECT_EQ(c.rgb[3 * j + static_cast<std::size_t>(ch)], bits_at(s[4 + static_cast<std::size_t>(ch)], k, 8));
    EXPECT_EQ(c.row[j], static_cast<std::int32_t>(bits_at(s[7], k, 11)));
    EXPECT_EQ(c.col[j], static_cast<std::int32_t>(bits_at(s[8], k, 9)));
  }
  expect_box(box(c), xml_bounds(o), 1e-5);
  const auto [imin_it, imax_it] = std::minmax_element(c.intensity.begin(), c.intensity.end());
  EXPECT_GE(*imin_it, 0.0F);
  EXPECT_LE(*imax_it, 1.0F);
  EXPECT_TRUE(notes_mention(r.report, "images2D skipped"));
  EXPECT_LE(*std::max_element(c.row.begin(), c.row.end()), static_cast<int>(elem(o.xml, "rowMaximum")));
  EXPECT_LE(*std::max_element(c.col.begin(), c.col.end()), static_cast<int>(elem(o.xml, "columnMaximum")));
}

TEST(E57Reader, ColourRepresentationTenBitScaledIntegersAndSixteenBitColour) {
  const fs::path p = sample("libe57-ColourRepresentation.e57");
  const Oracle o = oracle(p);
  const auto r = hp::load_cloud(p);
  const hp::Cloud& c = r.value;
  ASSERT_EQ(c.size(), total_records(o));
  expect_box(box(c), xml_bounds(o), 1e-9);
  // Prototype: x y z ScaledInteger −500..500 (10 bit), returnIndex/Count 1 bit, las:pointSourceId
  // 16 bit, colour 0..65535 (16 bit) without colorLimits: 8 bit = round(v · 255 / 65535).
  const auto s = streams_by_hand(o, std::stoull(attrs(o.xml, "points", "fileOffset").at(0)));
  ASSERT_EQ(s.size(), 9U);
  for (const std::size_t k : {std::size_t{0}, c.size() / 3, c.size() - 1}) {
    for (int a = 0; a < 3; ++a) {
      const double v = (static_cast<double>(bits_at(s[static_cast<std::size_t>(a)], k, 10)) - 500.0) * 1e-3;
      EXPECT_NEAR(c.xyz(a, static_cast<Eigen::Index>(k)), v, 1e-12);
    }
    for (int ch = 0; ch < 3; ++ch) {
      const double v16 = static_cast<double>(bits_at(s[6 + static_cast<std::size_t>(ch)], k, 16));
      EXPECT_EQ(c.rgb[3 * k + static_cast<std::size_t>(ch)], std::lround(v16 * 255.0 / 65535.0));
    }
  }
  EXPECT_TRUE(notes_mention(r.report, "las:pointSourceId"));
  EXPECT_TRUE(notes_mention(r.report, "returnIndex"));
}

TEST(E57Reader, TinyFloatRgbFirstAndLastPoints) {
  const fs::path p = sample("cryinc-tinyCartesianFloatRgb.e57");
  const Oracle o = oracle(p);
  const hp::Cloud c = hp::load_cloud(p).value;
  ASSERT_EQ(c.size(), total_records(o));
  ASSERT_EQ(c.size(), 2090U);
  expect_box(box(c), xml_bounds(o), 1e-5);
  const auto s = streams_by_hand(o, std::stoull(attrs(o.xml, "points", "fileOffset").at(0)));
  ASSERT_EQ(s.size(), 6U);
  for (const std::size_t k : {std::size_t{0}, c.size() - 1}) {
    for (int a = 0; a < 3; ++a)
      EXPECT_EQ(c.xyz(a, static_cast<Eigen::Index>(k)), get<float>(s[static_cast<std::size_t>(a)], 4 * k));
    for (int ch = 0; ch < 3; ++ch)
      EXPECT_EQ(c.rgb[3 * k + static_cast<std::size_t>(ch)], static_cast<unsigned char>(s[3 + static_cast<std::size_t>(ch)][k]));
  }
}

TEST(E57Reader, SphericalCoordinatesBecomeCartesian) {
  const fs::path p = sample("cryinc-tiny_spherical.e57");
  const Oracle o = oracle(p);
  const auto r = hp::load_cloud(p);
  const hp::Cloud& c = r.value;
  const std::size_t n = total_records(o);
  ASSERT_EQ(n, 360U);
  // Prototype: range, azimuth, elevation as double, sphericalInvalidState 0..2 (2 bit).
  const auto s = streams_by_hand(o, std::stoull(attrs(o.xml, "points", "fileOffset").at(0)));
  ASSERT_EQ(s.size(), 4U);
  std::size_t j = 0, skipped = 0;
  for (std::size_t k = 0; k < n; ++k) {
    if (bits_at(s[3], k, 2) != 0) {
      ++skipped;
      continue;
    }
    const double rr = get<double>(s[0], 8 * k), az = get<double>(s[1], 8 * k), el = get<double>(s[2], 8 * k);
    ASSERT_LT(j, c.size());
    EXPECT_NEAR(c.xyz(0, static_cast<Eigen::Index>(j)), rr * std::cos(el) * std::cos(az), 1e-12);
    EXPECT_NEAR(c.xyz(1, static_cast<Eigen::Index>(j)), rr * std::cos(el) * std::sin(az), 1e-12);
    EXPECT_NEAR(c.xyz(2, static_cast<Eigen::Index>(j)), rr * std::sin(el), 1e-12);
    EXPECT_NEAR(c.xyz.col(static_cast<Eigen::Index>(j)).norm(), rr, 1e-12);
    ++j;
  }
  EXPECT_EQ(c.size(), j);
  EXPECT_EQ(c.size() + skipped, n);
  if (skipped > 0) {
    EXPECT_TRUE(notes_mention(r.report, "invalid state"));
  }
}

TEST(E57Reader, TranslationWithoutRotationLandsTranslated) {
  const fs::path p = sample("pye57-translationWithoutRotation.e57");
  const Oracle o = oracle(p);
  ASSERT_EQ(o.xml.find("<rotation"), std::string::npos) << "the sample has no rotation element";
  const auto r = hp::load_cloud(p);
  const hp::Cloud& c = r.value;
  ASSERT_EQ(c.size(), 4U);
  // Prototype bounds (scan frame) x, y in [0, 1], z = 0; pose translation (4, 5, 6).
  const auto s = streams_by_hand(o, std::stoull(attrs(o.xml, "points", "fileOffset").at(0)));
  for (std::size_t k = 0; k < 4; ++k)
    for (int a = 0; a < 3; ++a)
      EXPECT_DOUBLE_EQ(c.xyz(a, static_cast<Eigen::Index>(k)),
                       static_cast<double>(get<float>(s[static_cast<std::size_t>(a)], 4 * k)) + 4.0 + a);
  expect_box(box(c), {{4, 5, 6}, {5, 6, 6}}, 1e-12);
  EXPECT_TRUE(notes_mention(r.report, "no rotation"));
}

TEST(E57Reader, PdalTwoScansMergeWithScanIds) {
  const fs::path p = sample("pdal-A_B.e57");
  const Oracle o = oracle(p);
  const auto counts = attrs(o.xml, "points", "recordCount");
  ASSERT_EQ(counts.size(), 2U);
  const auto r = hp::load_cloud(p);
  const hp::Cloud& c = r.value;
  const std::size_t n0 = std::stoull(counts[0]), n1 = std::stoull(counts[1]);
  ASSERT_EQ(n0, 2U);
  ASSERT_EQ(n1, 4U);
  ASSERT_EQ(c.size(), n0 + n1);
  ASSERT_TRUE(c.has_scan_id());
  for (std::size_t k = 0; k < c.size(); ++k) EXPECT_EQ(c.scan_id[k], k < n0 ? 0 : 1);
  Box want = xml_bounds(o, 0);
  const Box b1 = xml_bounds(o, 1);
  want.lo = want.lo.cwiseMin(b1.lo);
  want.hi = want.hi.cwiseMax(b1.hi);
  expect_box(box(c), want, 1e-5);
  // Intensity: Float, normalised with each scan's intensityLimits (XML).
  ASSERT_TRUE(c.has_intensity());
  ASSERT_TRUE(c.has_rgb());
  const auto offs = attrs(o.xml, "points", "fileOffset");
  for (std::size_t sc = 0; sc < 2; ++sc) {
    const auto s = streams_by_hand(o, std::stoull(offs[sc]));
    ASSERT_EQ(s.size(), 7U);
    const double lo = elem(o.xml, "intensityMinimum", sc), hi = elem(o.xml, "intensityMaximum", sc);
    const std::size_t base = sc == 0 ? 0 : n0, cnt = sc == 0 ? n0 : n1;
    for (std::size_t k = 0; k < cnt; ++k) {
      EXPECT_NEAR(c.intensity[base + k], (get<float>(s[3], 4 * k) - lo) / (hi - lo), 1e-6);
      EXPECT_EQ(c.xyz(0, static_cast<Eigen::Index>(base + k)), get<float>(s[0], 4 * k));
      for (int ch = 0; ch < 3; ++ch)
        EXPECT_EQ(c.rgb[3 * (base + k) + static_cast<std::size_t>(ch)], static_cast<unsigned char>(s[4 + static_cast<std::size_t>(ch)][k]));
    }
  }
}

TEST(E57Reader, PdalDifferentPrototypesMergeAndSayWhatWasDropped) {
  const fs::path p = sample("pdal-A_B_different_dims.e57");
  const Oracle o = oracle(p);
  const auto r = hp::load_cloud(p);
  ASSERT_EQ(r.value.size(), total_records(o));
  ASSERT_EQ(r.value.size(), 2U);
  EXPECT_EQ(r.value.scan_id, (std::vector<std::uint16_t>{0, 1}));
  EXPECT_FALSE(r.value.has_intensity());
  EXPECT_FALSE(r.value.has_rgb());
  EXPECT_TRUE(notes_mention(r.report, "'intensity' dropped"));
  EXPECT_TRUE(notes_mention(r.report, "'rgb' dropped"));
  EXPECT_DOUBLE_EQ(r.value.xyz(0, 0), elem(o.xml, "xMinimum", 0));
  EXPECT_DOUBLE_EQ(r.value.xyz(0, 1), elem(o.xml, "xMinimum", 1));
}

TEST(E57Reader, NormalsAreSkippedWithANote) {
  const fs::path p = sample("pye57-testWithNormals.e57");
  const Oracle o = oracle(p);
  const auto r = hp::load_cloud(p);
  ASSERT_EQ(r.value.size(), total_records(o));
  expect_box(box(r.value), xml_bounds(o), 1e-6);
  EXPECT_TRUE(notes_mention(r.report, "nor:normalX"));
}

TEST(E57Reader, ZeroScanFileIsAClearError) {
  const fs::path p = sample("nfdi4c-minimal-e57-1.0-unmodified-valid.e57");
  ASSERT_EQ(total_records(oracle(p)), 0U);
  const std::string e = load_error(p);
  EXPECT_NE(e.find("load_cloud: '" + p.string() + "'"), std::string::npos) << e;
  EXPECT_NE(e.find("holds no scans"), std::string::npos) << e;
}

// ---- synthetic two-scan file with known poses ---------------------------------------------------

TEST(E57Reader, SyntheticTwoScansWithPosesMergeIntoOneFrame) {
  std::mt19937 rng(57);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  Eigen::Matrix3Xd world(3, 1500);
  for (Eigen::Index i = 0; i < world.cols(); ++i) world.col(i) = Eigen::Vector3d(u(rng), u(rng), u(rng));
  // Scan 0: the first 800 points, seen from a pose rotated 30° about z then 10° about x;
  // scan 1: the other 700, rotated −75° about (1, 1, 1), offset far away.
  const Eigen::Quaterniond q0 = Eigen::AngleAxisd(0.5236, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.1745, Eigen::Vector3d::UnitX());
  const Eigen::Quaterniond q1(Eigen::AngleAxisd(-1.309, Eigen::Vector3d(1, 1, 1).normalized()));
  const Eigen::Vector3d t0(1.5, -2.0, 0.25), t1(1000.0, 2000.0, -30.0);
  SynthScan s0{(q0.conjugate().toRotationMatrix() * (world.leftCols(800).colwise() - t0)), {q0.w(), q0.x(), q0.y(), q0.z()}, t0};
  SynthScan s1{(q1.conjugate().toRotationMatrix() * (world.rightCols(700).colwise() - t1)), {q1.w(), q1.x(), q1.y(), q1.z()}, t1};
  const fs::path dir = hc::test::temp_dir("e57");
  const fs::path p = dir / "two_scans.e57";
  write_bytes(p, write_e57({s0, s1}));
  const auto r = hp::load_cloud(p);
  ASSERT_EQ(r.value.size(), 1500U);
  EXPECT_LE((r.value.xyz - world).cwiseAbs().maxCoeff(), 1e-9);
  for (std::size_t k = 0; k < 1500; ++k) ASSERT_EQ(r.value.scan_id[k], k < 800 ? 0 : 1);
  // The same scans without their poses do not land in the file frame (the test has teeth).
  SynthScan n0 = s0, n1 = s1;
  for (SynthScan* s : {&n0, &n1}) {
    s->q[0] = 1, s->q[1] = s->q[2] = s->q[3] = 0;
    s->t.setZero();
  }
  write_bytes(p, write_e57({n0, n1}));
  EXPECT_GT((hp::load_cloud(p).value.xyz - world).cwiseAbs().maxCoeff(), 0.1);
}

// ---- bad input -----------------------------------------------------------------------------

TEST(E57Reader, FlippedByteIsABadPageChecksumNamingTheOffset) {
  std::string b = read_bytes(sample("libe57-bunnyDouble.e57"));
  b[5 * 1024 + 100] = static_cast<char>(b[5 * 1024 + 100] ^ 0x10);
  const fs::path p = hc::test::temp_dir("e57") / "flipped.e57";
  write_bytes(p, b);
  const std::string e = load_error(p);
  EXPECT_NE(e.find("load_cloud: '" + p.string() + "'"), std::string::npos) << e;
  EXPECT_NE(e.find("checksum"), std::string::npos) << e;
  EXPECT_NE(e.find("physical offset 5120 "), std::string::npos) << e;
}

TEST(E57Reader, TruncatedFileIsAnError) {
  const std::string b = read_bytes(sample("libe57-bunnyDouble.e57"));
  const fs::path dir = hc::test::temp_dir("e57");
  write_bytes(dir / "cut.e57", b.substr(0, 100000));
  const std::string e = load_error(dir / "cut.e57");
  EXPECT_NE(e.find("truncated"), std::string::npos) << e;
  EXPECT_NE(e.find(std::to_string(b.size())), std::string::npos) << e;
  write_bytes(dir / "tiny.e57", b.substr(0, 20));
  EXPECT_NE(load_error(dir / "tiny.e57").find("48-byte"), std::string::npos);
}

TEST(E57Reader, XmlThatDoesNotParseIsAnError) {
  SynthScan s{Eigen::Matrix3Xd::Random(3, 10), {1, 0, 0, 0}, Eigen::Vector3d::Zero()};
  const fs::path p = hc::test::temp_dir("e57") / "badxml.e57";
  write_bytes(p, write_e57({s}, "<?xml version=\"1.0\"?><e57Root type=\"Structure\"><data3D type=\"Vector\">"));
  const std::string e = load_error(p);
  EXPECT_NE(e.find("XML section does not parse"), std::string::npos) << e;
}

TEST(E57Reader, BytestreamShorterThanItsCountIsAnError) {
  SynthScan s{Eigen::Matrix3Xd::Random(3, 10), {1, 0, 0, 0}, Eigen::Vector3d::Zero(), 11};
  const fs::path p = hc::test::temp_dir("e57") / "short.e57";
  write_bytes(p, write_e57({s}));
  const std::string e = load_error(p);
  EXPECT_NE(e.find("bytestream of field 'cartesianX' holds 80 bytes, expected 88"), std::string::npos) << e;
}

// ---- streamed scan by scan (point_stream.hpp, issue 14) -------------------------------------

namespace {

// Every chunk of a stream, concatenated (xyz, intensity, rgb), and the error it ended with.
struct Streamed {
  hc::pipeline::Cloud cloud;
  std::string error;
};

Streamed read_stream(const fs::path& p, std::size_t chunk) {
  Streamed out;
  std::vector<double> xyz;
  try {
    auto s = hc::pipeline::open_point_stream(p);
    EXPECT_TRUE(s->streamed());
    hc::pipeline::Cloud c;
    while (s->next(c, chunk)) {
      EXPECT_LE(c.size(), chunk);
      xyz.insert(xyz.end(), c.xyz.data(), c.xyz.data() + c.xyz.size());
      out.cloud.intensity.insert(out.cloud.intensity.end(), c.intensity.begin(), c.intensity.end());
      out.cloud.rgb.insert(out.cloud.rgb.end(), c.rgb.begin(), c.rgb.end());
    }
    out.cloud.crs = s->crs();
    std::vector<std::string> notes = s->notes();
    EXPECT_EQ(notes.back(), "data3D scans read one at a time");
    notes.pop_back();
    EXPECT_EQ(notes, hp::load_cloud(p).report.notes) << "the stream's notes are not load_cloud's";
    // Once failed, a stream stays failed; once done, it stays done.
    EXPECT_FALSE(s->next(c, chunk));
  } catch (const hc::InputError& e) {
    out.error = e.what();
  }
  out.cloud.xyz = Eigen::Map<Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(xyz.size() / 3));
  return out;
}

void expect_stream_equals_whole(const fs::path& p) {
  const hc::pipeline::Cloud whole = hp::load_cloud(p).value;
  for (const std::size_t chunk : {std::size_t{7}, std::size_t{1000}, std::size_t{1} << 20}) {
    const Streamed got = read_stream(p, chunk);
    ASSERT_EQ(got.error, "") << "chunk " << chunk;
    ASSERT_EQ(got.cloud.size(), whole.size()) << "chunk " << chunk;
    EXPECT_TRUE(got.cloud.xyz == whole.xyz) << "chunk " << chunk;
    EXPECT_EQ(got.cloud.intensity, whole.intensity) << "chunk " << chunk;
    EXPECT_EQ(got.cloud.rgb, whole.rgb) << "chunk " << chunk;
    EXPECT_EQ(got.cloud.crs, whole.crs) << "chunk " << chunk;
  }
}

}  // namespace

// Every real sample (one or several scans, cartesian and spherical, float and integer fields,
// colour, intensity, poses, scans with different fields) gives load_cloud's points, intensity,
// colour, CRS and notes in any chunking.
TEST(E57Stream, EveryRealSampleStreamsAsTheWholeRead) {
  std::size_t multi = 0, refused = 0;
  for (const auto& e : fs::directory_iterator(hc::test::scan_path("scanner_samples/e57"))) {
    if (e.path().extension() != ".e57") continue;
    SCOPED_TRACE(e.path().filename().string());
    const std::string whole_error = load_error(e.path());
    if (whole_error != "(no error)") {  // a sample without scans: the same error from the stream
      EXPECT_EQ(read_stream(e.path(), 1000).error, whole_error);
      ++refused;
      continue;
    }
    multi += hp::load_cloud(e.path()).value.scan_id.empty() ? 0U : 1U;
    expect_stream_equals_whole(e.path());
  }
  EXPECT_GE(multi, 1U) << "the samples cover several scans";
  EXPECT_LE(refused, 1U) << "only the sample without scans is refused";
}

// Two generated scans with poses, written in packets of 700 records: the same points.
TEST(E57Stream, TwoPosedScansStreamAsTheWholeRead) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  SynthScan s0{Eigen::Matrix3Xd(3, 2500), {0.9, 0.1, -0.3, 0.2}, Eigen::Vector3d(1.5, -2.0, 0.25)};
  SynthScan s1{Eigen::Matrix3Xd(3, 1700), {1, 0, 0, 0}, Eigen::Vector3d(100.0, 20.0, -3.0)};
  for (SynthScan* s : {&s0, &s1})
    for (Eigen::Index i = 0; i < s->local.cols(); ++i) s->local.col(i) = Eigen::Vector3d(u(rng), u(rng), u(rng));
  const fs::path p = hc::test::temp_dir("e57_stream") / "two.e57";
  write_bytes(p, write_e57({s0, s1}));
  expect_stream_equals_whole(p);
}

// Intensity without usable limits (a Float field without bounds) is normalised by the data's
// own range: the least and greatest non-NaN value of the scan's records, invalid ones included,
// found before the first record is handed out, so every chunking gives the same values. The
// oracle: that range computed here from the values written; a NaN stays NaN. 5000 records in
// packets of 700, states 0, 1 and 2 mixed, the extremes in the last packet and behind invalid
// records.
TEST(E57Stream, IntensityNormalisedByTheDataRangeIsTheSameInEveryChunking) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  SynthScan s{Eigen::Matrix3Xd(3, 5000), {1, 0, 0, 0}, Eigen::Vector3d::Zero()};
  for (Eigen::Index i = 0; i < s.local.cols(); ++i) s.local.col(i) = Eigen::Vector3d(u(rng), u(rng), u(rng));
  for (std::size_t i = 0; i < 5000; ++i) {
    s.state.push_back(static_cast<std::uint8_t>(i % 7 == 3 ? 2 : i % 11 == 5 ? 1 : 0));
    s.intensity.push_back(i % 97 == 0 ? std::numeric_limits<double>::quiet_NaN() : 100.0 + 50.0 * u(rng));
  }
  s.intensity[4998] = 12.5;   // the least, in the last packet, a valid record
  s.intensity[4997] = 301.0;  // the greatest, on a record of invalid state 2
  s.state[4997] = 2;
  const fs::path p = hc::test::temp_dir("e57_stream") / "intensity.e57";
  write_bytes(p, write_e57({s}));
  const auto whole = hp::load_cloud(p);
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const double v : s.intensity)
    if (!std::isnan(v)) lo = std::min(lo, v), hi = std::max(hi, v);
  ASSERT_EQ(lo, 12.5);
  ASSERT_EQ(hi, 301.0);
  std::vector<float> want;
  for (std::size_t i = 0; i < 5000; ++i)
    if (s.state[i] == 0) want.push_back(static_cast<float>(std::clamp((s.intensity[i] - lo) * (1.0 / (hi - lo)), 0.0, 1.0)));
  ASSERT_EQ(whole.value.intensity.size(), want.size());
  EXPECT_EQ(std::memcmp(whole.value.intensity.data(), want.data(), want.size() * sizeof(float)), 0);
  bool noted = false;
  for (const std::string& n : whole.report.notes)
    noted = noted || n.find("intensity normalised from [12.5, 301] (the data's own range (no usable limits))") != std::string::npos;
  EXPECT_TRUE(noted);
  for (const std::size_t chunk : {std::size_t{1}, std::size_t{7}, std::size_t{699}, std::size_t{1} << 20}) {
    const Streamed got = read_stream(p, chunk);
    ASSERT_EQ(got.error, "") << "chunk " << chunk;
    ASSERT_EQ(got.cloud.intensity.size(), want.size()) << "chunk " << chunk;
    EXPECT_EQ(std::memcmp(got.cloud.intensity.data(), want.data(), want.size() * sizeof(float)), 0) << "chunk " << chunk;
    EXPECT_TRUE(got.cloud.xyz == whole.value.xyz) << "chunk " << chunk;
  }
}

// A bad page inside the point data, and a bytestream shorter than its count: the stream fails
// with load_cloud's message (when opened or in next()), and a later call fails too.
TEST(E57Stream, ErrorsAreTheWholeReadsAndStick) {
  const fs::path dir = hc::test::temp_dir("e57_stream");
  std::string b = read_bytes(sample("libe57-bunnyDouble.e57"));
  b[5 * 1024 + 100] = static_cast<char>(b[5 * 1024 + 100] ^ 0x10);
  write_bytes(dir / "flipped.e57", b);
  SynthScan s{Eigen::Matrix3Xd::Random(3, 10), {1, 0, 0, 0}, Eigen::Vector3d::Zero(), 11};
  write_bytes(dir / "short.e57", write_e57({s}));
  // A packet of an unknown type after every record's bytes: the whole read reads every packet
  // and refuses it; so does the stream, when the scan's last records have been read.
  SynthScan t{Eigen::Matrix3Xd::Random(3, 1500), {1, 0, 0, 0}, Eigen::Vector3d::Zero()};
  t.trailing_packet_type = 7;
  write_bytes(dir / "trailing.e57", write_e57({t}));
  EXPECT_NE(load_error(dir / "trailing.e57").find("has packet type 7, expected 0 (index), 1 (data) or 2 (empty)"), std::string::npos)
      << load_error(dir / "trailing.e57");
  for (const char* name : {"flipped.e57", "short.e57", "trailing.e57"}) {
    SCOPED_TRACE(name);
    const std::string whole = load_error(dir / name);
    ASSERT_NE(whole, "(no error)");
    EXPECT_EQ(read_stream(dir / name, 100).error, whole);
  }
  // The scan is decoded a chunk at a time: the 10 records its packets hold come first (two
  // chunks of 5), and the 11th, which recordCount claims, fails the stream.
  auto st = hc::pipeline::open_point_stream(dir / "short.e57");
  hc::pipeline::Cloud c;
  ASSERT_TRUE(st->next(c, 5));
  EXPECT_EQ(c.size(), 5U);
  ASSERT_TRUE(st->next(c, 5));
  EXPECT_EQ(c.size(), 5U);
  EXPECT_THROW(st->next(c, 5), hc::InputError);
  try {
    st->next(c, 5);
    ADD_FAILURE() << "a failed stream went on";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("failed earlier"), std::string::npos) << e.what();
  }
}

// Scans without records among others: the whole read's merge drops the scan ids at each scan
// where one side has none (and takes the first non-empty scan whole); the stream's notes and
// points say the same.
TEST(E57Stream, EmptyScansMergeAsInTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("e57_stream");
  SynthScan a{Eigen::Matrix3Xd::Random(3, 10), {1, 0, 0, 0}, Eigen::Vector3d::Zero()};
  SynthScan none{Eigen::Matrix3Xd(3, 0), {1, 0, 0, 0}, Eigen::Vector3d::Zero()};
  SynthScan b{Eigen::Matrix3Xd::Random(3, 12), {1, 0, 0, 0}, Eigen::Vector3d(5, 0, 0)};
  write_bytes(dir / "middle.e57", write_e57({a, none, b}));
  write_bytes(dir / "first.e57", write_e57({none, a, b}));
  const auto middle = hp::load_cloud(dir / "middle.e57");
  ASSERT_EQ(middle.value.size(), 22U);
  std::size_t dropped = 0;
  for (const std::string& n : middle.report.notes) dropped += n.find("attribute 'scan_id' dropped") != std::string::npos;
  EXPECT_EQ(dropped, 2U) << "the oracle: at scan 1 and again at scan 2";
  expect_stream_equals_whole(dir / "middle.e57");
  expect_stream_equals_whole(dir / "first.e57");
}

// A scan whose every record has invalid state 2 (no point) keeps nothing, so the whole read's
// merge drops the scan ids at it and at the next scan; the stream counts the valid records
// from the state bytestream alone and says the same. The third scan mixes states 0, 1 and 2.
TEST(E57Stream, AScanWithOnlyInvalidRecordsMergesAsInTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("e57_stream");
  SynthScan a{Eigen::Matrix3Xd::Random(3, 10), {1, 0, 0, 0}, Eigen::Vector3d::Zero(), 0, std::vector<std::uint8_t>(10, 0)};
  SynthScan b{Eigen::Matrix3Xd::Random(3, 8), {1, 0, 0, 0}, Eigen::Vector3d::Zero(), 0, std::vector<std::uint8_t>(8, 2)};
  SynthScan c{Eigen::Matrix3Xd::Random(3, 1500), {1, 0, 0, 0}, Eigen::Vector3d(3, 0, 0), 0, {}};
  for (std::size_t i = 0; i < 1500; ++i) c.state.push_back(static_cast<std::uint8_t>(i % 3));
  write_bytes(dir / "invalid.e57", write_e57({a, b, c}));
  const auto whole = hp::load_cloud(dir / "invalid.e57");
  ASSERT_EQ(whole.value.size(), 10U + 500U);  // scan c keeps its state-0 records only
  std::size_t dropped = 0;
  for (const std::string& n : whole.report.notes) dropped += n.find("attribute 'scan_id' dropped") != std::string::npos;
  EXPECT_EQ(dropped, 2U) << "the oracle: at scan 1 and again at scan 2";
  expect_stream_equals_whole(dir / "invalid.e57");
}
