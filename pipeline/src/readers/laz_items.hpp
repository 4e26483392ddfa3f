#pragma once
/// @file laz_items.hpp
/// The per-item decoders of LAZ point data (private to the LAZ reader, read_laz.cpp).
///
/// A LAZ point is a sequence of items (LASzip VLR item list: type, size, version), each decoded
/// by its own decoder into the item's uncompressed LAS bytes, so a whole point comes out in the
/// LAS record layout of its point data format.
///   - Point-wise compressors (1, 2; point formats 0–5): one arithmetic stream per chunk shared
///     by all items (laz_point10.cpp: POINT10 v2, GPSTIME11 v2, RGB12 v2, BYTE v2).
///   - Layered compressor (3; point formats 6–10): each item splits its fields into layers,
///     each its own arithmetic stream whose byte count precedes the chunk's layers
///     (laz_point14.cpp: POINT14 v3, RGB14 v3, RGBNIR14 v3, BYTE14 v3).
/// In both, the first point of a chunk is stored raw and seeds every decoder's state.

#include "laz_arith.hpp"

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace hc::pipeline::detail::laz {

/// LASzip item types (LAZ specification, "items": type codes).
enum ItemType : std::uint16_t {
  kByte = 0,
  kPoint10 = 6,
  kGpsTime11 = 7,
  kRgb12 = 8,
  kWavePacket13 = 9,
  kPoint14 = 10,
  kRgb14 = 11,
  kRgbNir14 = 12,
  kWavePacket14 = 13,
  kByte14 = 14,
};

/// One entry of the LASzip VLR's item list.
struct Item {
  std::uint16_t type = 0;
  std::uint16_t size = 0;     ///< bytes of the item in the LAS record
  std::uint16_t version = 0;  ///< compression version of the item
};

/// Name of an item type for messages ("POINT10" …, or "type N").
std::string item_name(std::uint16_t type);

/// Decoder of one item in a point-wise (compressor 1/2) stream. A new decoder per chunk.
class PointwiseItem {
 public:
  virtual ~PointwiseItem() = default;
  /// Seeds the state from the chunk's raw first point (`raw`: the item's bytes).
  virtual void seed(const std::uint8_t* raw) = 0;
  /// Decodes the next point's item into `out` (the item's size in bytes).
  virtual void decode(ArithDecoder& d, std::uint8_t* out) = 0;
};

/// The decoder of `item` for the point-wise compressors, or nullptr if its type/version/size is
/// not one of POINT10 v2 (20 bytes), GPSTIME11 v2 (8), RGB12 v2 (6), BYTE v2 (n > 0).
std::unique_ptr<PointwiseItem> make_pointwise_item(const Item& item);

/// Decodes points 1 .. points − 1 of a point-wise chunk (compressors 1, 2) into `out`
/// (`record_length` bytes per point, items in `items` order): `raw` is the chunk's raw first
/// point, the arithmetic stream follows it and ends at `end` (bytes past it read as 0).
/// Precondition: make_pointwise_item accepts every item and their sizes sum to record_length.
/// Returns the bytes the stream requested past `end` (0 for a valid chunk). POINT10 [GPSTIME11]
/// [RGB12] [BYTE] in this order (LASzip's layout of formats 0–5) run in one fused loop.
std::size_t decode_pointwise_chunk(const std::vector<Item>& items, const std::uint8_t* raw, std::size_t record_length,
                                   const std::uint8_t* end, std::uint64_t points, std::uint8_t* out);

/// Decoder of one item in a layered (compressor 3) chunk. A new decoder per chunk.
class LayeredItem {
 public:
  virtual ~LayeredItem() = default;
  /// Number of layers (byte counts this item stores after the chunk's point count).
  virtual std::size_t layer_count() const = 0;
  /// Hands over the layers (`sizes[i]` bytes at `data[i]`, inside the chunk) and seeds the
  /// state from the chunk's raw first point; `context` is the scanner channel of that point.
  virtual void start(const std::vector<const std::uint8_t*>& data, const std::vector<std::size_t>& sizes,
                     const std::uint8_t* raw, std::uint32_t context) = 0;
  /// Decodes the next point's item into `out`. The POINT14 item sets `context` (the scanner
  /// channel) for the items after it.
  virtual void decode(std::uint8_t* out, std::uint32_t& context) = 0;
  /// Total bytes its decoders requested past the ends of their layers (0 for a valid chunk).
  virtual std::size_t overrun() const = 0;
};

/// The decoder of `item` for the layered compressor, or nullptr if its type/version is not one
/// of POINT14 v3, RGB14 v3, RGBNIR14 v3, BYTE14 v3.
std::unique_ptr<LayeredItem> make_layered_item(const Item& item);

/// GPS time decoder shared by GPSTIME11 v2 (`layered` false) and the GPS time layer of
/// POINT14 v3 (`layered` true): four sequences of (last time as i64 bits, last difference),
/// a difference predicted as a multiple of the last one (LAZ spec, GPS time layer).
class GpsTimeDecoder {
 public:
  explicit GpsTimeDecoder(bool layered);
  void seed(std::int64_t time_bits);
  void decode(ArithDecoder& d);  ///< the next time (v3: only called when it changed)
  std::int64_t value() const { return time_[last_]; }

 private:
  void add(std::int32_t diff);
  void full_time(ArithDecoder& d);
  void extreme(std::int32_t diff);
  bool step(ArithDecoder& d);
  bool layered_;
  std::int64_t time_[4] = {0, 0, 0, 0};
  std::int32_t diff_[4] = {0, 0, 0, 0};
  std::int32_t extreme_[4] = {0, 0, 0, 0};
  std::uint32_t last_ = 0, next_ = 0;
  SymbolModel multi_, zero_diff_;
  IntDecoder ic_;
};

/// RGB difference coding shared by RGB12 v2 and RGB14/RGBNIR14 v3: decodes the three 16-bit
/// channels of the next point from `last` with the byte-used model and six byte models.
void decode_rgb(ArithDecoder& d, SymbolModel& used, SymbolModel* diff, const std::uint16_t last[3],
                std::uint16_t out[3]);

/// Running median of the last five values (LASzip's predictor of x/y differences): starts at
/// five zeros; an insertion replaces the oldest value on the side it entered from.
class Median5 {
 public:
  std::int32_t get() const { return v_[2]; }
  void add(std::int32_t x);  // inline below: called twice per point

 private:
  std::int32_t v_[5] = {0, 0, 0, 0, 0};
  bool upper_ = true;
};

inline void Median5::add(std::int32_t x) {
  // Five sorted values; alternately the top or the bottom value is the one pushed out.
  if (upper_) {
    if (x < v_[2]) {
      v_[4] = v_[3];
      v_[3] = v_[2];
      if (x < v_[0]) {
        v_[2] = v_[1];
        v_[1] = v_[0];
        v_[0] = x;
      } else if (x < v_[1]) {
        v_[2] = v_[1];
        v_[1] = x;
      } else {
        v_[2] = x;
      }
    } else {
      if (x < v_[3]) {
        v_[4] = v_[3];
        v_[3] = x;
      } else {
        v_[4] = x;
      }
      upper_ = false;
    }
  } else {
    if (v_[2] < x) {
      v_[0] = v_[1];
      v_[1] = v_[2];
      if (v_[4] < x) {
        v_[2] = v_[3];
        v_[3] = v_[4];
        v_[4] = x;
      } else if (v_[3] < x) {
        v_[2] = v_[3];
        v_[3] = x;
      } else {
        v_[2] = x;
      }
    } else {
      if (v_[1] < x) {
        v_[0] = v_[1];
        v_[1] = x;
      } else {
        v_[0] = x;
      }
      upper_ = true;
    }
  }
}

namespace item_detail {
inline std::int32_t times(std::int64_t a, std::int32_t b) {
  return static_cast<std::int32_t>(static_cast<std::uint32_t>(a) * static_cast<std::uint32_t>(b));
}
inline std::uint32_t fold8(std::int32_t v) { return static_cast<std::uint32_t>(v) & 0xFFu; }
inline std::int32_t clamp8(std::int32_t v) { return v < 0 ? 0 : (v > 255 ? 255 : v); }
}  // namespace item_detail

/// RGB difference coding shared by RGB12 v2 and RGB14 v3 (same models and order): decodes the
/// three 16-bit channels of the next point from `last` (the previous point's channels).
[[gnu::always_inline]] inline void decode_rgb(ArithDecoder& d, SymbolModel& used, SymbolModel* diff, const std::uint16_t last[3],
                std::uint16_t out[3]) {
  const std::uint32_t s = d.symbol<true>(used);
  const auto lo = [](std::uint16_t v) { return static_cast<std::int32_t>(v & 0xFF); };
  const auto hi = [](std::uint16_t v) { return static_cast<std::int32_t>(v >> 8); };
  std::uint32_t r_lo = (s & 1) ? item_detail::fold8(static_cast<std::int32_t>(d.symbol<true>(diff[0])) + lo(last[0])) : lo(last[0]);
  std::uint32_t r_hi = (s & 2) ? item_detail::fold8(static_cast<std::int32_t>(d.symbol<true>(diff[1])) + hi(last[0])) : hi(last[0]);
  out[0] = static_cast<std::uint16_t>(r_lo | (r_hi << 8));
  if (!(s & 64)) {
    out[1] = out[0];
    out[2] = out[0];
    return;
  }
  std::int32_t change = static_cast<std::int32_t>(r_lo) - lo(last[0]);
  std::uint32_t g_lo, b_lo, g_hi, b_hi;
  g_lo = (s & 4) ? item_detail::fold8(static_cast<std::int32_t>(d.symbol<true>(diff[2])) + item_detail::clamp8(change + lo(last[1]))) : lo(last[1]);
  if (s & 16) {
    const std::int32_t c = (change + (static_cast<std::int32_t>(g_lo) - lo(last[1]))) / 2;
    b_lo = item_detail::fold8(static_cast<std::int32_t>(d.symbol<true>(diff[4])) + item_detail::clamp8(c + lo(last[2])));
  } else {
    b_lo = lo(last[2]);
  }
  change = static_cast<std::int32_t>(r_hi) - hi(last[0]);
  g_hi = (s & 8) ? item_detail::fold8(static_cast<std::int32_t>(d.symbol<true>(diff[3])) + item_detail::clamp8(change + hi(last[1]))) : hi(last[1]);
  if (s & 32) {
    const std::int32_t c = (change + (static_cast<std::int32_t>(g_hi) - hi(last[1]))) / 2;
    b_hi = item_detail::fold8(static_cast<std::int32_t>(d.symbol<true>(diff[5])) + item_detail::clamp8(c + hi(last[2])));
  } else {
    b_hi = hi(last[2]);
  }
  out[1] = static_cast<std::uint16_t>(g_lo | (g_hi << 8));
  out[2] = static_cast<std::uint16_t>(b_lo | (b_hi << 8));
}

// GPS time constants (LAZ spec, GPS time layer): multiples up to 500 of the last difference,
// −1..−10 as 501..510; then (v2) 511 unchanged, 512 new full time, 513.. switch sequence, or
// (v3, where "unchanged" is a flag of the XY layer) 511 new full time, 512.. switch sequence.
inline constexpr std::uint32_t kMulti = 500;
inline constexpr std::int32_t kMultiMinus = -10;
inline constexpr std::uint32_t kMultiLimit = kMulti - kMultiMinus + 1;  // 511: first code that is not a multiple

inline GpsTimeDecoder::GpsTimeDecoder(bool layered)
    : layered_(layered), multi_(layered ? 515 : 516), zero_diff_(layered ? 5 : 6), ic_(32, 9) {}

inline void GpsTimeDecoder::seed(std::int64_t t) {
  for (int i = 0; i < 4; ++i) {
    time_[i] = 0;
    diff_[i] = 0;
    extreme_[i] = 0;
  }
  time_[0] = t;
  last_ = next_ = 0;
}

inline void GpsTimeDecoder::add(std::int32_t diff) {
  time_[last_] = static_cast<std::int64_t>(static_cast<std::uint64_t>(time_[last_]) +
                                           static_cast<std::uint64_t>(static_cast<std::int64_t>(diff)));
}

[[gnu::always_inline]] inline void GpsTimeDecoder::full_time(ArithDecoder& d) {
  next_ = (next_ + 1) & 3;
  const auto high = static_cast<std::uint32_t>(
      ic_.decode(d, static_cast<std::int32_t>(static_cast<std::uint64_t>(time_[last_]) >> 32), 8));
  const std::uint32_t low = d.int32();
  time_[next_] = static_cast<std::int64_t>((static_cast<std::uint64_t>(high) << 32) | low);
  last_ = next_;
  diff_[last_] = 0;
  extreme_[last_] = 0;
}

inline void GpsTimeDecoder::extreme(std::int32_t diff) {
  if (++extreme_[last_] > 3) {
    diff_[last_] = diff;
    extreme_[last_] = 0;
  }
}

[[gnu::always_inline]] inline void GpsTimeDecoder::decode(ArithDecoder& d) {
  // A sequence switch decodes again; a valid stream switches at most a few times per point,
  // the bound keeps corrupt input from looping.
  for (int guard = 0; guard < 8; ++guard) {
    if (step(d)) return;
  }
}

[[gnu::always_inline]] inline bool GpsTimeDecoder::step(ArithDecoder& d) {
  const std::uint32_t base = layered_ ? 0 : 1;  // v2 spends code 0 on "unchanged"
  if (diff_[last_] == 0) {
    const std::uint32_t s = d.symbol(zero_diff_);
    if (s == base) {
      diff_[last_] = ic_.decode(d, 0, 0);
      add(diff_[last_]);
      extreme_[last_] = 0;
    } else if (s == base + 1) {
      full_time(d);
    } else if (s > base + 1) {
      last_ = (last_ + s - (base + 1)) & 3;
      return false;
    }
    return true;
  }
  const std::uint32_t s = d.symbol<true>(multi_);
  const std::uint32_t full_code = layered_ ? kMultiLimit : kMultiLimit + 1;
  if (s < kMultiLimit) {
    // One integer-decoder call site for every multiple (the decoder is inlined, so this keeps
    // the code small): prediction, context, and what the difference does to the sequence.
    enum { kPlain, kExtreme, kLikeLast } kind = kPlain;
    std::int32_t pred;
    std::uint32_t context;
    if (s == 1) {
      pred = diff_[last_];
      context = 1;
      kind = kLikeLast;
    } else if (s == 0) {
      pred = 0;
      context = 7;
      kind = kExtreme;
    } else if (s < kMulti) {
      pred = item_detail::times(s, diff_[last_]);
      context = s < 10 ? 2 : 3;
    } else if (s == kMulti) {
      pred = item_detail::times(kMulti, diff_[last_]);
      context = 4;
      kind = kExtreme;
    } else {
      const std::int32_t f = static_cast<std::int32_t>(kMulti) - static_cast<std::int32_t>(s);
      if (f > kMultiMinus) {
        pred = item_detail::times(f, diff_[last_]);
        context = 5;
      } else {
        pred = item_detail::times(kMultiMinus, diff_[last_]);
        context = 6;
        kind = kExtreme;
      }
    }
    const std::int32_t diff = ic_.decode(d, pred, context);
    add(diff);
    if (kind == kExtreme) extreme(diff);
    else if (kind == kLikeLast) extreme_[last_] = 0;
  } else if (s == full_code) {
    full_time(d);
  } else if (s > full_code) {
    last_ = (last_ + s - full_code) & 3;
    return false;
  }
  return true;  // v2 code 511: unchanged
}

}  // namespace hc::pipeline::detail::laz
