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
//     dx of class m; dy: (32 bit, 22 contexts: (n == 1) + min(even(k_x), 20)) likewise, where
//     k_x is the bucket of dx; z: (32 bit, 20 contexts: (n == 1) + min(even((k_x + k_y)/2), 18))
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

template <class T>
T load(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <class T>
void store(std::uint8_t* p, T v) {
  std::memcpy(p, &v, sizeof v);
}

std::uint32_t even(std::uint32_t k) { return k & ~1u; }

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

class Point10 final : public PointwiseItem {
 public:
  void seed(const std::uint8_t* raw) override { std::memcpy(last_, raw, 20); }
  void decode(ArithDecoder& d, std::uint8_t* out) override {
    const std::uint32_t changed = d.symbol(changed_);
    if (changed & 32) last_[14] = static_cast<std::uint8_t>(d.symbol(return_byte_.at(last_[14])));
    const std::uint32_t r = last_[14] & 7u, n = (last_[14] >> 3) & 7u;
    const std::uint32_t m = kReturnClass8[n][r];
    const std::uint32_t l = n > r ? n - r : r - n;
    if (changed & 16) {
      last_intensity_[m] = static_cast<std::uint16_t>(intensity_.decode(d, last_intensity_[m], m < 3 ? m : 3));
    }
    store<std::uint16_t>(last_ + 12, last_intensity_[m]);
    if (changed & 8) last_[15] = static_cast<std::uint8_t>(d.symbol(classification_.at(last_[15])));
    if (changed & 4) {
      const std::uint32_t dir = (last_[14] >> 6) & 1u;
      last_[16] = static_cast<std::uint8_t>(d.symbol(scan_angle_[dir]) + last_[16]);
    }
    if (changed & 2) last_[17] = static_cast<std::uint8_t>(d.symbol(user_data_.at(last_[17])));
    if (changed & 1) {
      store<std::uint16_t>(last_ + 18,
                           static_cast<std::uint16_t>(source_id_.decode(d, load<std::uint16_t>(last_ + 18), 0)));
    }
    const std::int32_t dx = dx_.decode(d, dx_median_[m].get(), n == 1);
    store<std::int32_t>(last_, static_cast<std::int32_t>(static_cast<std::uint32_t>(load<std::int32_t>(last_)) +
                                                          static_cast<std::uint32_t>(dx)));
    dx_median_[m].add(dx);
    const std::uint32_t kx = dx_.last_k();
    const std::int32_t dy = dy_.decode(d, dy_median_[m].get(), (n == 1) + (kx < 20 ? even(kx) : 20));
    store<std::int32_t>(last_ + 4, static_cast<std::int32_t>(static_cast<std::uint32_t>(load<std::int32_t>(last_ + 4)) +
                                                              static_cast<std::uint32_t>(dy)));
    dy_median_[m].add(dy);
    const std::uint32_t kz = (dx_.last_k() + dy_.last_k()) / 2;
    last_height_[l] = z_.decode(d, last_height_[l], (n == 1) + (kz < 18 ? even(kz) : 18));
    store<std::int32_t>(last_ + 8, last_height_[l]);
    std::memcpy(out, last_, 20);
  }

 private:
  std::uint8_t last_[20] = {};
  std::uint16_t last_intensity_[16] = {};
  std::int32_t last_height_[8] = {};
  Median5 dx_median_[16], dy_median_[16];
  SymbolModel changed_{64};
  ModelBank return_byte_{256}, classification_{256}, user_data_{256};
  SymbolModel scan_angle_[2] = {SymbolModel(256), SymbolModel(256)};
  IntDecoder intensity_{16, 4}, source_id_{16, 1};
  IntDecoder dx_{32, 2}, dy_{32, 22}, z_{32, 20};
};

std::int32_t times(std::int64_t a, std::int32_t b) {
  return static_cast<std::int32_t>(static_cast<std::uint32_t>(a) * static_cast<std::uint32_t>(b));
}

class GpsTime11 final : public PointwiseItem {
 public:
  void seed(const std::uint8_t* raw) override { gps_.seed(load<std::int64_t>(raw)); }
  void decode(ArithDecoder& d, std::uint8_t* out) override {
    gps_.decode(d);
    store<std::int64_t>(out, gps_.value());
  }

 private:
  GpsTimeDecoder gps_{false};
};

std::uint32_t fold8(std::int32_t v) { return static_cast<std::uint32_t>(v) & 0xFFu; }
std::int32_t clamp8(std::int32_t v) { return v < 0 ? 0 : (v > 255 ? 255 : v); }

}  // namespace

/// RGB difference coding shared by RGB12 v2 and RGB14 v3 (same models and order): decodes the
/// three 16-bit channels of the next point from `last` (the previous point's channels).
void decode_rgb(ArithDecoder& d, SymbolModel& used, SymbolModel* diff, const std::uint16_t last[3],
                std::uint16_t out[3]) {
  const std::uint32_t s = d.symbol(used);
  const auto lo = [](std::uint16_t v) { return static_cast<std::int32_t>(v & 0xFF); };
  const auto hi = [](std::uint16_t v) { return static_cast<std::int32_t>(v >> 8); };
  std::uint32_t r_lo = (s & 1) ? fold8(static_cast<std::int32_t>(d.symbol(diff[0])) + lo(last[0])) : lo(last[0]);
  std::uint32_t r_hi = (s & 2) ? fold8(static_cast<std::int32_t>(d.symbol(diff[1])) + hi(last[0])) : hi(last[0]);
  out[0] = static_cast<std::uint16_t>(r_lo | (r_hi << 8));
  if (!(s & 64)) {
    out[1] = out[0];
    out[2] = out[0];
    return;
  }
  std::int32_t change = static_cast<std::int32_t>(r_lo) - lo(last[0]);
  std::uint32_t g_lo, b_lo, g_hi, b_hi;
  g_lo = (s & 4) ? fold8(static_cast<std::int32_t>(d.symbol(diff[2])) + clamp8(change + lo(last[1]))) : lo(last[1]);
  if (s & 16) {
    const std::int32_t c = (change + (static_cast<std::int32_t>(g_lo) - lo(last[1]))) / 2;
    b_lo = fold8(static_cast<std::int32_t>(d.symbol(diff[4])) + clamp8(c + lo(last[2])));
  } else {
    b_lo = lo(last[2]);
  }
  change = static_cast<std::int32_t>(r_hi) - hi(last[0]);
  g_hi = (s & 8) ? fold8(static_cast<std::int32_t>(d.symbol(diff[3])) + clamp8(change + hi(last[1]))) : hi(last[1]);
  if (s & 32) {
    const std::int32_t c = (change + (static_cast<std::int32_t>(g_hi) - hi(last[1]))) / 2;
    b_hi = fold8(static_cast<std::int32_t>(d.symbol(diff[5])) + clamp8(c + hi(last[2])));
  } else {
    b_hi = hi(last[2]);
  }
  out[1] = static_cast<std::uint16_t>(g_lo | (g_hi << 8));
  out[2] = static_cast<std::uint16_t>(b_lo | (b_hi << 8));
}

namespace {

class Rgb12 final : public PointwiseItem {
 public:
  void seed(const std::uint8_t* raw) override { std::memcpy(last_, raw, 6); }
  void decode(ArithDecoder& d, std::uint8_t* out) override {
    std::uint16_t next[3];
    decode_rgb(d, used_, diff_, last_, next);
    std::memcpy(last_, next, 6);
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
  void seed(const std::uint8_t* raw) override { std::memcpy(last_.data(), raw, last_.size()); }
  void decode(ArithDecoder& d, std::uint8_t* out) override {
    for (std::size_t i = 0; i < last_.size(); ++i) {
      last_[i] = static_cast<std::uint8_t>(last_[i] + d.symbol(models_[i]));
    }
    std::memcpy(out, last_.data(), last_.size());
  }

 private:
  std::vector<std::uint8_t> last_;
  std::vector<SymbolModel> models_;
};

}  // namespace

// GPS time constants (LAZ spec, GPS time layer): multiples up to 500 of the last difference,
// −1..−10 as 501..510; then (v2) 511 unchanged, 512 new full time, 513.. switch sequence, or
// (v3, where "unchanged" is a flag of the XY layer) 511 new full time, 512.. switch sequence.
constexpr std::uint32_t kMulti = 500;
constexpr std::int32_t kMultiMinus = -10;
constexpr std::uint32_t kMultiLimit = kMulti - kMultiMinus + 1;  // 511: first code that is not a multiple

GpsTimeDecoder::GpsTimeDecoder(bool layered)
    : layered_(layered), multi_(layered ? 515 : 516), zero_diff_(layered ? 5 : 6), ic_(32, 9) {}

void GpsTimeDecoder::seed(std::int64_t t) {
  for (int i = 0; i < 4; ++i) {
    time_[i] = 0;
    diff_[i] = 0;
    extreme_[i] = 0;
  }
  time_[0] = t;
  last_ = next_ = 0;
}

void GpsTimeDecoder::add(std::int32_t diff) {
  time_[last_] = static_cast<std::int64_t>(static_cast<std::uint64_t>(time_[last_]) +
                                           static_cast<std::uint64_t>(static_cast<std::int64_t>(diff)));
}

void GpsTimeDecoder::full_time(ArithDecoder& d) {
  next_ = (next_ + 1) & 3;
  const auto high = static_cast<std::uint32_t>(
      ic_.decode(d, static_cast<std::int32_t>(static_cast<std::uint64_t>(time_[last_]) >> 32), 8));
  const std::uint32_t low = d.int32();
  time_[next_] = static_cast<std::int64_t>((static_cast<std::uint64_t>(high) << 32) | low);
  last_ = next_;
  diff_[last_] = 0;
  extreme_[last_] = 0;
}

void GpsTimeDecoder::extreme(std::int32_t diff) {
  if (++extreme_[last_] > 3) {
    diff_[last_] = diff;
    extreme_[last_] = 0;
  }
}

void GpsTimeDecoder::decode(ArithDecoder& d) {
  // A sequence switch decodes again; a valid stream switches at most a few times per point,
  // the bound keeps corrupt input from looping.
  for (int guard = 0; guard < 8; ++guard) {
    if (step(d)) return;
  }
}

bool GpsTimeDecoder::step(ArithDecoder& d) {
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
  const std::uint32_t s = d.symbol(multi_);
  const std::uint32_t full_code = layered_ ? kMultiLimit : kMultiLimit + 1;
  if (s == 1) {
    add(ic_.decode(d, diff_[last_], 1));
    extreme_[last_] = 0;
  } else if (s < kMultiLimit) {
    std::int32_t diff;
    if (s == 0) {
      diff = ic_.decode(d, 0, 7);
      extreme(diff);
    } else if (s < kMulti) {
      diff = ic_.decode(d, times(s, diff_[last_]), s < 10 ? 2 : 3);
    } else if (s == kMulti) {
      diff = ic_.decode(d, times(kMulti, diff_[last_]), 4);
      extreme(diff);
    } else {
      const std::int32_t f = static_cast<std::int32_t>(kMulti) - static_cast<std::int32_t>(s);
      if (f > kMultiMinus) {
        diff = ic_.decode(d, times(f, diff_[last_]), 5);
      } else {
        diff = ic_.decode(d, times(kMultiMinus, diff_[last_]), 6);
        extreme(diff);
      }
    }
    add(diff);
  } else if (s == full_code) {
    full_time(d);
  } else if (s > full_code) {
    last_ = (last_ + s - full_code) & 3;
    return false;
  }
  return true;  // v2 code 511: unchanged
}

std::unique_ptr<PointwiseItem> make_pointwise_item(const Item& item) {
  if (item.version != 2) return nullptr;
  switch (item.type) {
    case kPoint10: return std::make_unique<Point10>();
    case kGpsTime11: return std::make_unique<GpsTime11>();
    case kRgb12: return std::make_unique<Rgb12>();
    case kByte: return std::make_unique<Bytes>(item.size);
    default: return nullptr;
  }
}

}  // namespace hc::pipeline::detail::laz
