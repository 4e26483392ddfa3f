// LAZ reader: LASzip-compressed LAS, written clean room. Sources of facts: the LASzip
// specification document "LASzip for LAS 1.4 (native extension)" (LAStools repository,
// LASzip/design/specification.rst; below "spec"), M. Isenburg, "LASzip: lossless compression
// of LiDAR data", PE&RS 79(2), 2013, and LASzip's reader (lasreadpoint.cpp, the v2/v3 item
// readers) read for facts only (field order, model sizes, contexts); no code from LASzip,
// laz-perf or laz-rs. COPC files (.copc.laz, COPC 1.0 specification) are LAZ files whose chunks are the
// octree's nodes; they are read as plain LAZ, every chunk in file order.
//
// Facts followed:
//   - the LAS header and VLRs are stored as in LAS; bit 7 (older writers: bit 6) of the point
//     data format byte marks compressed data (spec, first paragraph);
//   - the LASzip VLR (user id "laszip encoded", record 22204), little-endian: compressor u16
//     (0 none, 1 point-wise, 2 point-wise chunked, 3 layered chunked), coder u16 (0 arithmetic),
//     version major u8, minor u8, revision u16, options u32, chunk size u32 (0xFFFFFFFF =
//     variable), number and offset of special EVLRs i64 ×2, item count u16, then per item
//     type u16, size u16, version u16 (LASzip reader, VLR unpacking);
//   - chunked compressors: the point data starts with an i64 offset of the chunk table (−1 when
//     the writer could not seek back: then the offset is the file's last 8 bytes); the chunks
//     follow. The table: version u32 (0), chunk count u32, then per chunk (variable chunk
//     size only) the point count and the byte count, each coded by an integer compressor
//     (32 bit, 2 contexts: 0 counts, 1 bytes) predicted by the previous chunk's value, in one
//     arithmetic stream (spec, "LAZ File Layout"; LASzip reader, chunk table);
//   - point-wise chunk: the first point raw (LAS record layout), then one arithmetic stream for
//     the rest (laz_point10.cpp);
//   - layered chunk: the first point raw, u32 point count, every item's layer byte counts (u32
//     each, items in order), then the layers in the same order (laz_point14.cpp);
//   - compressor 1 (not chunked): one point-wise chunk from the start of the point data.
// The decompressed records then go through the LAS reader's field decoding (las_records.hpp),
// so a LAZ file yields exactly what its LAS twin does.

#include "byte_io.hpp"
#include "las_records.hpp"
#include "laz_items.hpp"
#include "../posix_io.hpp"
#include "readers.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>
#include <memory>
#include <string_view>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace hc::pipeline::detail {

namespace {

struct LaszipVlr {
  std::uint16_t compressor = 0, coder = 0;
  int major = 0, minor = 0, revision = 0;
  std::uint32_t chunk_size = 0;
  std::vector<laz::Item> items;
};

struct Chunk {
  std::size_t begin = 0, end = 0;  ///< byte range in the file
  std::uint64_t points = 0;
};

std::string compressor_name(std::uint16_t c) {
  switch (c) {
    case 0: return "0 (none)";
    case 1: return "1 (point-wise)";
    case 2: return "2 (point-wise chunked)";
    case 3: return "3 (layered chunked)";
    default: return std::to_string(c);
  }
}

/// Where the chunks are and how they are coded: the LASzip VLR and the chunk table.
struct LazLayout {
  LaszipVlr z;
  bool layered = false;
  std::vector<std::size_t> item_offset;  ///< byte offset of each item in a record
  std::vector<Chunk> chunks;
  std::vector<std::string> notes;  ///< the compressor note, and COPC's
};

[[noreturn]] void laz_fail(const std::string& name, const std::string& what) {
  throw InputError("load_cloud: " + name + " " + what);
}

/// Reads the LASzip VLR and the chunk table of a LAZ file whose header (parsed with
/// `compressed` = true) is `header`; `bytes` is the whole file (in memory or mapped). Only the
/// VLR, the chunk table offset and the chunk table are read. Throws hc::InputError naming the
/// file and the VLR field, item or table entry.
LazLayout laz_layout(std::string_view bytes, const std::string& name, const LasHeader& header) {
  const std::size_t size = bytes.size();
  const char* const b = bytes.data();
  const auto fail = [&](const std::string& what) { laz_fail(name, what); };

  const std::size_t record_length = header.record_length;
  const std::uint64_t count = header.count;
  const std::size_t offset = header.offset;

  // The LASzip VLR.
  const Vlr* zip = nullptr;
  bool copc = false;
  for (const Vlr& v : header.vlrs) {
    if (v.user_id == "laszip encoded" && v.record_id == 22204) zip = &v;
    if (v.user_id == "copc") copc = true;
  }
  if (!zip) {
    fail("has no LASzip VLR (user id 'laszip encoded', record 22204): expected a LAZ file written by LASzip "
         "or a compatible writer");
  }
  if (zip->length < 34) {
    fail("has a LASzip VLR of " + std::to_string(zip->length) + " bytes: expected at least 34");
  }
  LazLayout L;
  LaszipVlr& z = L.z;
  z.compressor = load_le<std::uint16_t>(zip->data + 0);
  z.coder = load_le<std::uint16_t>(zip->data + 2);
  z.major = static_cast<unsigned char>(zip->data[4]);
  z.minor = static_cast<unsigned char>(zip->data[5]);
  z.revision = load_le<std::uint16_t>(zip->data + 6);
  z.chunk_size = load_le<std::uint32_t>(zip->data + 12);
  const std::size_t n_items = load_le<std::uint16_t>(zip->data + 32);
  if (zip->length < 34 + 6 * n_items) {
    fail("has a LASzip VLR of " + std::to_string(zip->length) + " bytes listing " + std::to_string(n_items) +
         " items: expected " + std::to_string(34 + 6 * n_items) + " bytes");
  }
  std::size_t item_bytes = 0;
  std::string item_list;
  for (std::size_t i = 0; i < n_items; ++i) {
    const char* p = zip->data + 34 + 6 * i;
    laz::Item it{load_le<std::uint16_t>(p), load_le<std::uint16_t>(p + 2), load_le<std::uint16_t>(p + 4)};
    item_bytes += it.size;
    item_list += (item_list.empty() ? "" : ", ") + laz::item_name(it.type) + " v" + std::to_string(it.version);
    z.items.push_back(it);
  }
  if (z.coder != 0) {
    fail("has LASzip coder " + std::to_string(z.coder) + ": only the arithmetic coder (0) is defined");
  }
  if (z.compressor < 1 || z.compressor > 3) {
    fail("has LASzip compressor " + std::to_string(z.compressor) +
         ": expected 1 (point-wise), 2 (point-wise chunked) or 3 (layered chunked)");
  }
  if (n_items == 0 || item_bytes != record_length) {
    fail("has LASzip items (" + item_list + ") of " + std::to_string(item_bytes) + " bytes in total: expected " +
         std::to_string(record_length) + " bytes, the point record length of the header");
  }
  L.layered = z.compressor == 3;
  {
    std::size_t at = 0;
    for (const laz::Item& it : z.items) {
      L.item_offset.push_back(at);
      at += it.size;
      const bool ok = L.layered ? static_cast<bool>(laz::make_layered_item(it)) : static_cast<bool>(laz::make_pointwise_item(it));
      if (!ok) {
        fail("uses LASzip item " + laz::item_name(it.type) + " version " + std::to_string(it.version) + " (" +
             std::to_string(it.size) + " bytes) with compressor " + compressor_name(z.compressor) +
             ": supported are POINT10, GPSTIME11, RGB12, BYTE version 2 (compressors 1, 2) and POINT14, RGB14, "
             "RGBNIR14, BYTE14 version 3 (compressor 3)");
      }
    }
    const std::uint16_t first = z.items.front().type;
    const bool point14 = first == laz::kPoint14;
    if ((first != laz::kPoint10 && !point14) || point14 != (header.format >= 6)) {
      fail("has point data format " + std::to_string(header.format) + " with first LASzip item " +
           laz::item_name(first) + ": expected POINT10 for formats 0–5 and POINT14 for formats 6–10");
    }
    const std::size_t item_size = point14 ? 30 : 20;
    if (z.items.front().size != item_size) {
      fail("has a " + laz::item_name(first) + " item of " + std::to_string(z.items.front().size) +
           " bytes: expected " + std::to_string(item_size));
    }
  }

  // A plausibility bound before any table or buffer is sized, so a corrupt count cannot ask
  // for gigabytes: even constant points cost LASzip well over 1/4096 byte each.
  constexpr std::uint64_t kMaxPointsPerByte = 4096;
  if (count / kMaxPointsPerByte > size - offset) {
    fail("declares " + std::to_string(count) + " points in " + std::to_string(size - offset) +
         " bytes of compressed point data: more than " + std::to_string(kMaxPointsPerByte) +
         " points per byte is not plausible (corrupt header or truncated file)");
  }

  // Chunks.
  std::vector<Chunk>& chunks = L.chunks;
  if (z.compressor == 1) {
    chunks.push_back({offset, size, count});
  } else {
    if (size - offset < 8) fail("ends at byte " + std::to_string(size) + " inside the chunk table offset at byte " + std::to_string(offset));
    std::int64_t table = load_le<std::int64_t>(b + offset);
    if (table == -1) {
      table = size >= 8 ? load_le<std::int64_t>(b + size - 8) : -1;  // written at the end by a streaming writer
    }
    if (table < static_cast<std::int64_t>(offset + 8) || static_cast<std::uint64_t>(table) > size - 8) {
      fail("stores its chunk table offset " + std::to_string(table) + " at byte " + std::to_string(offset) +
           ": expected an offset between " + std::to_string(offset + 8) + " and " + std::to_string(size - 8) +
           " (file of " + std::to_string(size) + " bytes; truncated file?)");
    }
    const std::size_t t = static_cast<std::size_t>(table);
    const std::uint32_t table_version = load_le<std::uint32_t>(b + t);
    const std::uint64_t n_chunks = load_le<std::uint32_t>(b + t + 4);
    if (table_version != 0) {
      fail("has chunk table version " + std::to_string(table_version) + " at byte " + std::to_string(t) +
           ": expected 0");
    }
    const bool variable = z.chunk_size == 0xFFFFFFFFu;
    if (!variable && z.chunk_size == 0) fail("has a LASzip chunk size of 0: expected a positive size or 0xFFFFFFFF");
    const std::uint64_t expect_chunks = variable ? 0 : (count + z.chunk_size - 1) / z.chunk_size;
    const std::uint64_t room = (t - offset - 8) / record_length;  // each chunk starts with a raw point
    if (n_chunks == 0 || n_chunks > count || n_chunks > room || (!variable && n_chunks != expect_chunks)) {
      fail("has a chunk table (byte " + std::to_string(t) + ") of " + std::to_string(n_chunks) + " chunks for " +
           std::to_string(count) + " points" +
           (variable ? std::string() : " in chunks of " + std::to_string(z.chunk_size) + " (expected " +
                                           std::to_string(expect_chunks) + " chunks)"));
    }
    laz::ArithDecoder d;
    const auto* tb = reinterpret_cast<const std::uint8_t*>(b);
    d.start(tb + t + 8, tb + size);
    laz::IntDecoder ic(32, 2);
    std::uint64_t begin = offset + 8, left = count;
    std::int32_t last_points = 0, last_bytes = 0;
    for (std::uint64_t i = 0; i < n_chunks; ++i) {
      std::uint64_t points;
      if (variable) {
        last_points = ic.decode(d, last_points, 0);
        points = static_cast<std::uint32_t>(last_points);
      } else {
        points = std::min<std::uint64_t>(z.chunk_size, left);
      }
      last_bytes = ic.decode(d, last_bytes, 1);
      const std::uint64_t chunk_bytes = static_cast<std::uint32_t>(last_bytes);
      if (points == 0 || points > left || chunk_bytes > t - begin) {
        fail("has a chunk table entry " + std::to_string(i) + " of " + std::to_string(points) + " points and " +
             std::to_string(chunk_bytes) + " bytes at byte " + std::to_string(begin) + ": expected at most " +
             std::to_string(left) + " points and " + std::to_string(t - begin) +
             " bytes before the chunk table (byte " + std::to_string(t) + ")");
      }
      chunks.push_back({static_cast<std::size_t>(begin), static_cast<std::size_t>(begin + chunk_bytes), points});
      begin += chunk_bytes;
      left -= points;
    }
    if (left != 0 || d.overrun() > 0) {
      fail("has a chunk table at byte " + std::to_string(t) + " covering " + std::to_string(count - left) + " of " +
           std::to_string(count) + " points: truncated or corrupt chunk table");
    }
  }
  L.notes.push_back("LAZ: LASzip " + std::to_string(z.major) + "." + std::to_string(z.minor) + "r" +
                    std::to_string(z.revision) + ", compressor " + compressor_name(z.compressor) + ", " +
                    std::to_string(chunks.size()) + " chunk(s)" +
                    (z.chunk_size == 0xFFFFFFFFu ? std::string(" of variable size")
                                                 : " of " + std::to_string(z.chunk_size) + " points") +
                    ", items " + item_list);
  if (copc) {
    L.notes.push_back("COPC file: read as plain LAZ, every chunk in file order; the COPC info and hierarchy "
                      "records are skipped");
  }
  return L;
}

/// Decompresses chunk c of L into L.chunks[c].points LAS records of record_length bytes at
/// `out`. `bytes` holds the chunk's bytes, [chunks[c].begin, chunks[c].end) of the file.
/// Throws hc::InputError naming the file, the chunk and what is wrong.
void decode_laz_chunk(const LazLayout& L, std::size_t c, const std::uint8_t* bytes, std::size_t record_length,
                      std::uint8_t* out, const std::string& name) {
  const Chunk& ch = L.chunks[c];
  const std::size_t len = ch.end - ch.begin;
  const auto chunk_fail = [&](const std::string& what) {
    laz_fail(name, "chunk " + std::to_string(c) + " (bytes " + std::to_string(ch.begin) + " to " + std::to_string(ch.end) +
                       ", " + std::to_string(ch.points) + " points): " + what);
  };
  if (len < record_length) {
    chunk_fail("too short for its raw first point of " + std::to_string(record_length) + " bytes (truncated?)");
  }
  const std::uint8_t* raw = bytes;
  std::memcpy(out, raw, record_length);
  std::uint8_t* rec = out + record_length;
  if (!L.layered) {
    const std::size_t over = laz::decode_pointwise_chunk(L.z.items, raw, record_length, bytes + len, ch.points, rec);
    if (over > 0) chunk_fail("compressed stream ends " + std::to_string(over) + " bytes early (truncated or corrupt)");
    return;
  }
  std::size_t at = record_length;  // relative to the chunk's first byte
  if (len - at < 4) chunk_fail("ends before its point count (truncated?)");
  at += 4;  // the chunk's own point count; the chunk table's count is the one used (as LASzip does)
  std::vector<std::unique_ptr<laz::LayeredItem>> dec;
  std::vector<std::vector<std::size_t>> sizes;
  for (const laz::Item& it : L.z.items) {
    dec.push_back(laz::make_layered_item(it));
    std::vector<std::size_t> s(dec.back()->layer_count());
    for (auto& v : s) {
      if (len - at < 4) chunk_fail("ends inside its layer sizes at byte " + std::to_string(ch.begin + at) + " (truncated?)");
      v = load_le<std::uint32_t>(reinterpret_cast<const char*>(bytes + at));
      at += 4;
    }
    sizes.push_back(std::move(s));
  }
  const std::uint32_t channel = (raw[15] >> 4) & 3u;
  for (std::size_t i = 0; i < dec.size(); ++i) {
    std::vector<const std::uint8_t*> data;
    for (std::size_t n : sizes[i]) {
      if (n > len - at) {
        chunk_fail(laz::item_name(L.z.items[i].type) + " layer of " + std::to_string(n) + " bytes at byte " +
                   std::to_string(ch.begin + at) + " runs past the chunk's end (truncated or corrupt)");
      }
      data.push_back(bytes + at);
      at += n;
    }
    dec[i]->start(data, sizes[i], raw + L.item_offset[i], channel);
  }
  for (std::uint64_t p = 1; p < ch.points; ++p, rec += record_length) {
    // As LASzip: the context handed to the items after POINT14 starts at 0 for every point
    // and is set by POINT14 only when the scanner channel changes.
    std::uint32_t context = 0;
    for (std::size_t i = 0; i < dec.size(); ++i) dec[i]->decode(rec + L.item_offset[i], context);
    if ((p & 1023u) == 0) {  // a corrupt layer: stop early, the check below rejects the chunk
      std::size_t over = 0;
      for (const auto& dd : dec) over += dd->overrun();
      if (over > 16) break;
    }
  }
  std::size_t over = 0;
  for (const auto& dd : dec) over += dd->overrun();
  if (ch.points > 1 && over > 0) chunk_fail("compressed layers end " + std::to_string(over) + " bytes early (truncated or corrupt)");
}

// A LAZ file decompressed chunk by chunk (point_stream.hpp): one chunk's compressed bytes and
// records in memory at a time.
class LazStream final : public LasRecordStream {
 public:
  LazStream(int fd, std::string name, const LasHeader& header, LazLayout layout, const LoadOptions* options,
            std::vector<std::string> format_notes, std::vector<std::string> crs_notes, std::string crs)
      : LasRecordStream(std::move(name), header, options, std::move(format_notes), std::move(crs_notes), std::move(crs),
                        large_file_key(fd)),
        fd_(fd), layout_(std::move(layout)) {}
  ~LazStream() override { ::close(fd_); }
  LazStream(const LazStream&) = delete;
  LazStream& operator=(const LazStream&) = delete;

 private:
  std::size_t next_records(std::size_t max, const char*& records) override {
    if (pos_ == have_) load_chunk(next_chunk_++);
    const std::size_t n = std::min(max, have_ - pos_);
    records = records_.data() + pos_ * record_length_;
    pos_ += n;
    return n;
  }

  void each_record_block(const std::function<void(const char*, std::size_t)>& f) override {
    for (std::size_t c = 0; c < layout_.chunks.size(); ++c) {
      load_chunk(c);
      f(records_.data(), have_);
    }
    have_ = pos_ = next_chunk_ = 0;
  }

  // Reads chunk c's bytes (pread) and decompresses its records into records_.
  void load_chunk(std::size_t c) {
    const Chunk& ch = layout_.chunks[c];
    const std::size_t len = ch.end - ch.begin;
    bytes_.resize(len);
    if (!pread_full(fd_, bytes_.data(), len, ch.begin)) {
      throw InputError("load_cloud: " + name_ + ": truncated or unreadable in LAZ chunk " + std::to_string(c) + " (bytes " +
                       std::to_string(ch.begin) + " to " + std::to_string(ch.end) + ")");
    }
    records_.resize(static_cast<std::size_t>(ch.points) * record_length_);
    decode_laz_chunk(layout_, c, reinterpret_cast<const std::uint8_t*>(bytes_.data()), record_length_,
                     reinterpret_cast<std::uint8_t*>(records_.data()), name_);
    have_ = static_cast<std::size_t>(ch.points);
    pos_ = 0;
  }

  int fd_;
  LazLayout layout_;
  std::size_t next_chunk_ = 0, have_ = 0, pos_ = 0;  // records_ holds have_ records; pos_ given out
  std::vector<char> bytes_, records_;
};

}  // namespace

std::unique_ptr<char[]> decompress_laz(const ScanSource& source, LasHeader& header) {
  const LazLayout L = laz_layout(source.bytes, source.display_name, header);
  const std::size_t record_length = header.record_length;
  auto records = std::make_unique_for_overwrite<char[]>(static_cast<std::size_t>(header.count) * record_length);
  auto* out = reinterpret_cast<std::uint8_t*>(records.get());
  const auto* file = reinterpret_cast<const std::uint8_t*>(source.bytes.data());
  for (std::size_t c = 0; c < L.chunks.size(); ++c) {
    decode_laz_chunk(L, c, file + L.chunks[c].begin, record_length, out, source.display_name);
    out += L.chunks[c].points * record_length;
  }
  for (const std::string& note : L.notes) header.notes.push_back(note);
  return records;
}

ReadResult read_laz(const ScanSource& source) {
  LasHeader header = parse_las_header(source, true);
  const std::unique_ptr<char[]> records = decompress_laz(source, header);
  return decode_las_records(source, std::move(header), records.get());
}

std::unique_ptr<PointStream> open_laz_stream(const std::filesystem::path& path, const std::string& name,
                                             const LoadOptions* options) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return nullptr;
  FileMapping map;  // only the header, the (E)VLRs and the chunk table are read through it
  if (!map.map(fd)) {
    ::close(fd);
    return nullptr;
  }
  try {
    LasHeader header = parse_las_header(map.bytes(), name, true);
    LazLayout layout = laz_layout(map.bytes(), name, header);
    std::vector<std::string> format_notes = std::move(header.notes);
    for (const std::string& note : layout.notes) format_notes.push_back(note);
    for (std::string& note : las_format_notes(header)) format_notes.push_back(std::move(note));
    std::vector<std::string> crs_notes;
    std::string crs = las_crs(header, crs_notes);
    header.vlrs.clear();  // they point into the mapping
    return std::make_unique<LazStream>(fd, name, header, std::move(layout), options, std::move(format_notes),
                                       std::move(crs_notes), std::move(crs));
  } catch (...) {
    ::close(fd);
    throw;
  }
}

}  // namespace hc::pipeline::detail
