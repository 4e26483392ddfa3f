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

/// The decoder of `item` for the point-wise compressors, or nullptr if its type/version is not
/// one of POINT10 v2, GPSTIME11 v2, RGB12 v2, BYTE v2 (sizes are checked by the caller).
std::unique_ptr<PointwiseItem> make_pointwise_item(const Item& item);

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

}  // namespace hc::pipeline::detail::laz
