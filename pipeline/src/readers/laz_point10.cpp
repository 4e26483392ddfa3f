// Point-wise LAZ item decoders (compressors 1 and 2, LAS point formats 0–5): POINT10 v2,
// GPSTIME11 v2, RGB12 v2, BYTE v2. Written clean room from the LASzip specification (items
// POINT10/GPSTIME11/RGB12/BYTE version 2; order of operations and model sizes checked against
// LASzip's v2 item readers as facts) and M. Isenburg, "LASzip:
// lossless compression of LiDAR data", PE&RS 79(2) 2013. Facts followed (no code carried over):
//   POINT10 (20 bytes: X Y Z i32, intensity u16, return byte, classification, scan angle rank
//   i8, user data, point source ID u16):
//   - a 64-symbol model codes which fields changed: bit 5 the return byte, 4 intensity,
//     3 classification, 2 scan angle rank, 1 user data, 0 point source ID;
//   - the return byte, classification and user data are coded with 256-symbol models chosen
//     by the previous value of the same byte; the scan angle rank as a difference modulo 256
//     with a model per scan direction flag;
//   - intensity: integer compressor (16 bit, 4 contexts) predicted by the last intensity of the
//     same return class m (context min(m, 3)); point source ID: integer compressor (16 bit);
//   - m = return map[n][r] (16 classes), l = return level[n][r] = |n − r| (8 classes);
//   - dx: integer compressor (32 bit, 2 contexts: n == 1) predicted by the median of the last 5
//     dx of class m; dy: (32 bit, 22 contexts: (n == 1) + min(even_index(k_x), 20)) likewise, where
//     k_x is the bucket of dx; z: (32 bit, 20 contexts: (n == 1) + min(even_index((k_x + k_y)/2), 18))
//     predicted by the last z of level l.
//   GPSTIME11 (f64 as i64 bits): four sequences of (last time, last difference); 6-symbol
//   model when the last difference is 0 (0 same, 1 32-bit difference, 2 new 64-bit time,
//   ≥ 3 switch sequence), else a 516-symbol model (1: difference like the last, < 500 a
//   multiple, 500 large multiple, 501–510 negative multiples, 511 unchanged, 512 new 64-bit
//   time, > 512 switch); an integer compressor (32 bit, 9 contexts); a difference becomes the
//   new "last difference" after 4 extreme multiples in a row.
//   RGB12 (3 × u16): a 128-symbol model says which bytes changed (bit 6: any of G/B); red low
//   and high bytes coded as differences mod 256; green and blue predicted from red's change
//   (clamped to 0..255), blue from the mean of red's and green's changes.
//   BYTE (n bytes): byte i as a difference mod 256 with its own 256-symbol model.

#include "byte_io.hpp"
#include "laz_items.hpp"

#include <array>
#include <cstring>

namespace hc::pipeline::detail::laz {

// Return class of (number of returns n, return number r), both 0..7: the 16-class map of the
// LAZ specification (valid pairs 1 ≤ r ≤ n ≤ 5 enumerate 0..14; the rest share classes).
constexpr std::uint8_t kReturnClass8[8][8] = {
    {15, 14, 13, 12, 11, 10, 9, 8},   {14, 0, 1, 3, 6, 10, 10, 9},     {13, 1, 2, 4, 7, 11, 11, 10},
    {12, 3, 4, 5, 8, 12, 12, 11},     {11, 6, 7, 8, 9, 13, 13, 12},    {10, 10, 11, 12, 13, 14, 14, 13},
    {9, 10, 11, 12, 13, 14, 15, 14},  {8, 9, 10, 11, 12, 13, 14, 15},
};

std::string item_name(std::uint16_t type) {
  switch (type) {
    case kByte: return "BYTE";
    case kPoint10: return "POINT10";
    case kGpsTime11: return "GPSTIME11";
    case kRgb12: return "RGB12";
    case kWavePacket13: return "WAVEPACKET13";
    case kPoint14: return "POINT14";
    case kRgb14: return "RGB14";
    case kRgbNir14: return "RGBNIR14";
    case kWavePacket14: return "WAVEPACKET14";
    case kByte14: return "BYTE14";
    default: return "type " + std::to_string(type);
  }
}

namespace {


/// A lazily created 256-symbol model per previous byte value.
class ModelBank {
 public:
  explicit ModelBank(std::uint32_t symbols) : symbols_(symbols) {}
  SymbolModel& at(std::size_t i) {
    if (!models_[i]) models_[i] = std::make_unique<SymbolModel>(symbols_);
    return *models_[i];
  }

 private:
  std::uint32_t symbols_;
  std::array<std::unique_ptr<SymbolModel>, 256> models_;
};

// The item decoders keep their state in typed members (never a byte array), and write the
// item's bytes only once per point, at the end: stores through a byte pointer may alias
// anything, so a byte-array state would make the compiler reload every model pointer and the
// decoder's interval after each of them. Each has an always-inlined `step` that the fused chunk
// loop below (decode_pointwise_chunk) calls on a decoder held in local variables.

class Point10 final : public PointwiseItem {
 public:
  void seed(const std::uint8_t* raw) override {
    x_ = load_le<std::int32_t>(raw);
    y_ = load_le<std::int32_t>(raw + 4);
    z_out_ = load_le<std::int32_t>(raw + 8);
    intensity_out_ = load_le<std::uint16_t>(raw + 12);
    return_byte_value_ = raw[14];
    class_ = raw[15];
    angle_ = raw[16];
    user_ = raw[17];
    source_ = load_le<std::uint16_t>(raw + 18);
  }
  void decode(ArithDecoder& d, std::uint8_t* out) override { step(d, out); }

  [[gnu::always_inline]] void step(ArithDecoder& d, std::uint8_t* out) {
    const std::uint32_t changed = d.symbol<true>(changed_);
    if (changed & 32) return_byte_value_ = d.symbol<true>(return_byte_.at(return_byte_value_));
    const std::uint32_t r = return_byte_value_ & 7u, n = (return_byte_value_ >> 3) & 7u;
    const std::uint32_t m = kReturnClass8[n][r];
    const std::uint32_t l = n > r ? n - r : r - n;
    if (changed & 16) {
      last_intensity_[m] = static_cast<std::uint16_t>(intensity_.decode(d, last_intensity_[m], m < 3 ? m : 3));
    }
    intensity_out_ = last_intensity_[m];
    if (changed & 8) class_ = d.symbol<true>(classification_.at(class_));
    if (changed & 4) {
      const std::uint32_t dir = (return_byte_value_ >> 6) & 1u;
      angle_ = (d.symbol<true>(scan_angle_[dir]) + angle_) & 0xFFu;
    }
    if (changed & 2) user_ = d.symbol<true>(user_data_.at(user_));
    if (changed & 1) source_ = static_cast<std::uint16_t>(source_id_.decode(d, source_, 0));
    const std::uint32_t first = n == 1;
    const std::int32_t dx = dx_.decode(d, dx_median_[m].get(), first);
    x_ = static_cast<std::int32_t>(static_cast<std::uint32_t>(x_) + static_cast<std::uint32_t>(dx));
    dx_median_[m].add(dx);
    const std::uint32_t kx = dx_.last_k();
    const std::int32_t dy = dy_.decode(d, dy_median_[m].get(), first + (kx < 20 ? even_index(kx) : 20));
    y_ = static_cast<std::int32_t>(static_cast<std::uint32_t>(y_) + static_cast<std::uint32_t>(dy));
    dy_median_[m].add(dy);
    const std::uint32_t kz = (kx + dy_.last_k()) / 2;
    z_out_ = z_.decode(d, last_height_[l], first + (kz < 18 ? even_index(kz) : 18));
    last_height_[l] = z_out_;
    store_le<std::int32_t>(out, x_);
    store_le<std::int32_t>(out + 4, y_);
    store_le<std::int32_t>(out + 8, z_out_);
    store_le<std::uint16_t>(out + 12, intensity_out_);
    out[14] = static_cast<std::uint8_t>(return_byte_value_);
    out[15] = static_cast<std::uint8_t>(class_);
    out[16] = static_cast<std::uint8_t>(angle_);
    out[17] = static_cast<std::uint8_t>(user_);
    store_le<std::uint16_t>(out + 18, source_);
  }

 private:
  std::int32_t x_ = 0, y_ = 0, z_out_ = 0;
  std::uint32_t return_byte_value_ = 0, class_ = 0, angle_ = 0, user_ = 0;
  std::uint16_t intensity_out_ = 0, source_ = 0;
  std::uint16_t last_intensity_[16] = {};
  std::int32_t last_height_[8] = {};
  Median5 dx_median_[16], dy_median_[16];
  SymbolModel changed_{64};
  ModelBank return_byte_{256}, classification_{256}, user_data_{256};
  SymbolModel scan_angle_[2] = {SymbolModel(256), SymbolModel(256)};
  IntDecoder intensity_{16, 4}, source_id_{16, 1};
  IntDecoder dx_{32, 2}, dy_{32, 22}, z_{32, 20};
};

class GpsTime11 final : public PointwiseItem {
 public:
  void seed(const std::uint8_t* raw) override { gps_.seed(load_le<std::int64_t>(raw)); }
  void decode(ArithDecoder& d, std::uint8_t* out) override { step(d, out); }
  [[gnu::always_inline]] void step(ArithDecoder& d, std::uint8_t* out) {
    gps_.decode(d);
    store_le<std::int64_t>(out, gps_.value());
  }

 private:
  GpsTimeDecoder gps_{false};
};

class Rgb12 final : public PointwiseItem {
 public:
  void seed(const std::uint8_t* raw) override { std::memcpy(last_, raw, 6); }
  void decode(ArithDecoder& d, std::uint8_t* out) override { step(d, out); }
  [[gnu::always_inline]] void step(ArithDecoder& d, std::uint8_t* out) {
    std::uint16_t next[3];
    decode_rgb(d, used_, diff_, last_, next);
    last_[0] = next[0];
    last_[1] = next[1];
    last_[2] = next[2];
    std::memcpy(out, next, 6);
  }

 private:
  std::uint16_t last_[3] = {0, 0, 0};
  SymbolModel used_{128};
  SymbolModel diff_[6] = {SymbolModel(256), SymbolModel(256), SymbolModel(256),
                          SymbolModel(256), SymbolModel(256), SymbolModel(256)};
};

class Bytes final : public PointwiseItem {
 public:
  explicit Bytes(std::size_t n) : last_(n, 0), models_(n, SymbolModel(256)) {}
  void seed(const std::uint8_t* raw) override {
    for (std::size_t i = 0; i < last_.size(); ++i) last_[i] = raw[i];
  }
  void decode(ArithDecoder& d, std::uint8_t* out) override { step(d, out); }
  [[gnu::always_inline]] void step(ArithDecoder& d, std::uint8_t* out) {
    const std::size_t n = last_.size();
    std::uint32_t* last = last_.data();
    SymbolModel* models = models_.data();
    for (std::size_t i = 0; i < n; ++i) last[i] = (last[i] + d.symbol<true>(models[i])) & 0xFFu;
    for (std::size_t i = 0; i < n; ++i) out[i] = static_cast<std::uint8_t>(last[i]);
  }

 private:
  std::vector<std::uint32_t> last_;
  std::vector<SymbolModel> models_;
};

/// A stream this many bytes past its end is corrupt or truncated: decoding stops there (checked
/// every 1024 points) instead of running the rest of a possibly huge declared count on zeros.
constexpr std::size_t kGiveUpBytes = 16;

/// The points after the first of one chunk whose items are POINT10 [GPSTIME11] [RGB12] [BYTE]
/// in this order (how LASzip lays out formats 0–5): one loop, no indirect calls, the
/// arithmetic decoder in a local (registers) for the whole chunk.
template <bool kGps, bool kRgb, bool kBytes>
std::size_t run_chunk(Point10& p10, GpsTime11* gps, Rgb12* rgb, Bytes* extra, const std::size_t offsets[4],
                      const std::uint8_t* begin, const std::uint8_t* end, std::uint64_t points, std::uint8_t* out,
                      std::size_t record_length) {
  ArithDecoder d;
  d.start(begin, end);
  for (std::uint64_t p = 1; p < points; ++p, out += record_length) {
    p10.step(d, out);
    if constexpr (kGps) gps->step(d, out + offsets[1]);
    if constexpr (kRgb) rgb->step(d, out + offsets[2]);
    if constexpr (kBytes) extra->step(d, out + offsets[3]);
    if ((p & 1023u) == 0 && d.overrun() > kGiveUpBytes) break;  // the caller rejects the chunk
  }
  return d.overrun();
}

}  // namespace

std::size_t decode_pointwise_chunk(const std::vector<Item>& items, const std::uint8_t* raw, std::size_t record_length,
                                   const std::uint8_t* end, std::uint64_t points, std::uint8_t* out) {
  if (points <= 1) return 0;
  const std::uint8_t* begin = raw + record_length;
  // The fused loop for the usual item order; anything else item by item through the
  // virtual interface.
  std::size_t at = 0, i = 0, offsets[4] = {0, 0, 0, 0};
  bool fused = !items.empty() && items[0].type == kPoint10 && items[0].version == 2;
  bool has[4] = {true, false, false, false};
  const std::uint16_t order[4] = {kPoint10, kGpsTime11, kRgb12, kByte};
  for (std::size_t slot = 0; fused && slot < 4 && i < items.size(); ++slot) {
    if (items[i].type != order[slot]) continue;
    if (items[i].version != 2) fused = false;
    has[slot] = true;
    offsets[slot] = at;
    at += items[i].size;
    ++i;
  }
  // The fused loop writes 20, 8 and 6 bytes for POINT10, GPSTIME11 and RGB12: only with the
  // sizes the specification gives them (the header check rejects others; checked here too).
  for (const Item& it : items) {
    if ((it.type == kPoint10 && it.size != 20) || (it.type == kGpsTime11 && it.size != 8) ||
        (it.type == kRgb12 && it.size != 6)) {
      fused = false;
    }
  }
  fused = fused && i == items.size() && at == record_length;
  if (fused) {
    Point10 p10;
    p10.seed(raw);
    GpsTime11 gps;
    Rgb12 rgb;
    Bytes extra(has[3] ? items.back().size : 0);
    if (has[1]) gps.seed(raw + offsets[1]);
    if (has[2]) rgb.seed(raw + offsets[2]);
    if (has[3]) extra.seed(raw + offsets[3]);
    using Run = std::size_t (*)(Point10&, GpsTime11*, Rgb12*, Bytes*, const std::size_t*, const std::uint8_t*,
                                const std::uint8_t*, std::uint64_t, std::uint8_t*, std::size_t);
    static constexpr Run kRuns[8] = {run_chunk<false, false, false>, run_chunk<false, false, true>,
                                     run_chunk<false, true, false>,  run_chunk<false, true, true>,
                                     run_chunk<true, false, false>,  run_chunk<true, false, true>,
                                     run_chunk<true, true, false>,   run_chunk<true, true, true>};
    const Run run = kRuns[(has[1] ? 4 : 0) + (has[2] ? 2 : 0) + (has[3] ? 1 : 0)];
    return run(p10, &gps, &rgb, &extra, offsets, begin, end, points, out, record_length);
  }
  std::vector<std::unique_ptr<PointwiseItem>> dec;
  std::vector<std::size_t> offset;
  at = 0;
  for (const Item& it : items) {
    dec.push_back(make_pointwise_item(it));
    dec.back()->seed(raw + at);
    offset.push_back(at);
    at += it.size;
  }
  ArithDecoder d;
  d.start(begin, end);
  for (std::uint64_t p = 1; p < points; ++p, out += record_length) {
    for (std::size_t k = 0; k < dec.size(); ++k) dec[k]->decode(d, out + offset[k]);
    if ((p & 1023u) == 0 && d.overrun() > kGiveUpBytes) break;  // the caller rejects the chunk
  }
  return d.overrun();
}

std::unique_ptr<PointwiseItem> make_pointwise_item(const Item& item) {
  if (item.version != 2) return nullptr;
  switch (item.type) {
    // Sizes as the LAZ specification defines them: a decoder writes exactly its item's bytes.
    case kPoint10: return item.size == 20 ? std::make_unique<Point10>() : nullptr;
    case kGpsTime11: return item.size == 8 ? std::make_unique<GpsTime11>() : nullptr;
    case kRgb12: return item.size == 6 ? std::make_unique<Rgb12>() : nullptr;
    case kByte: return item.size > 0 ? std::make_unique<Bytes>(item.size) : nullptr;
    default: return nullptr;
  }
}

}  // namespace hc::pipeline::detail::laz
