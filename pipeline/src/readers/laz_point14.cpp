// Layered LAZ item decoders (compressor 3, LAS 1.4 point formats 6–10): POINT14 v3, RGB14 v3,
// RGBNIR14 v3, BYTE14 v3. Written clean room from the LAZ specification ("LASzip for LAS 1.4
// (native extension)": chunk layout, layers, contexts) with the order of operations and model
// sizes checked against the LASzip reader as a source of facts only (no code carried over).
// Facts followed:
//   - every item keeps four contexts, one per scanner channel; a context is set up on first use
//     from the previous point (of whichever channel), the chunk's raw first point for the first;
//   - POINT14 layers, in order: (0) channel, returns and XY, (1) Z, (2) classification,
//     (3) flags, (4) intensity, (5) scan angle, (6) user data, (7) point source ID, (8) GPS
//     time. An empty layer means that field does not change within the chunk;
//   - layer 0 starts with a 128-symbol "changed" code (bit 6 scanner channel, 5 point source,
//     4 GPS time, 3 scan angle, 2 number of returns, 1–0 return number: same, +1, −1, other),
//     coded in one of 8 contexts: previous point first return (1) + last return (2) + its GPS
//     time changed (4); a channel change codes (new − old − 1) mod 4 with a 3-symbol model;
//     number of returns with a 16-symbol model per previous n; "other" return number with a
//     16-symbol model per previous r when the GPS time changed, else r + 2 + (0..12) mod 16;
//   - m = 6-class return map[n][r], l = min(|n − r|, 7); cpr = 2·(r == 1) + (r ≥ n);
//   - dx, dy as in POINT10 v2 with medians indexed by 2m + (GPS time changed); z by last z of
//     level l; classification: 256-symbol model per 2·(last class & 31) + (cpr == 3);
//     flags (edge << 5 | direction << 4 | classification flags): 64-symbol model per previous
//     flags; intensity: integer compressor (16 bit, 4 contexts = cpr) predicted by the last
//     intensity of slot 2·cpr + (GPS time changed), slots seeded with the first intensity;
//     scan angle (i16): integer compressor (16 bit, 2 contexts = GPS time changed) from the
//     last angle, only when flagged; user data: 256-symbol model per previous value / 4; point
//     source: integer compressor (16 bit) when flagged; GPS time as GPSTIME11 with 5/515-symbol
//     models, when flagged;
//   - RGB14: RGB12's coding in its own layer; RGBNIR14 adds an NIR layer (4-symbol "bytes
//     changed" model, two 256-symbol byte models); BYTE14: one layer per extra byte;
//   - the items after POINT14 receive the scanner channel only on points where it changes
//     (else context 0), and switching to an already used context keeps predicting from the
//     previous context's last values — both as LASzip writes them.

#include "byte_io.hpp"
#include "laz_items.hpp"

#include <array>
#include <cstring>

namespace hc::pipeline::detail::laz {

namespace {

// 6-class return map of the LAZ specification (number of returns n = row, return number r =
// column, both 0..15).
constexpr std::uint8_t kReturnClass16[16][16] = {
    {0, 1, 2, 3, 4, 5, 3, 4, 4, 5, 5, 5, 5, 5, 5, 5}, {1, 0, 1, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3},
    {2, 1, 2, 4, 4, 4, 4, 4, 4, 4, 4, 3, 3, 3, 3, 3}, {3, 3, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4},
    {4, 3, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4}, {5, 3, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4},
    {3, 3, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4}, {4, 3, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4},
    {4, 3, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4}, {5, 3, 4, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4},
    {5, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 4, 4, 4},
    {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5, 4, 4}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5, 4},
    {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5},
};

std::int32_t wrap_add(std::int32_t a, std::int32_t b) {
  return static_cast<std::int32_t>(static_cast<std::uint32_t>(a) + static_cast<std::uint32_t>(b));
}

/// The fields of a point format 6 record (LAS 1.4 R15 table 12) that POINT14 codes.
struct Fields14 {
  std::int32_t x = 0, y = 0, z = 0;
  std::uint16_t intensity = 0;
  std::uint32_t r = 0, n = 0;             // return number, number of returns (4 bits each)
  std::uint32_t class_flags = 0, channel = 0, direction = 0, edge = 0;
  std::uint32_t classification = 0, user_data = 0;
  std::int16_t scan_angle = 0;
  std::uint16_t source = 0;
  std::int64_t gps = 0;                   // f64 bits
  bool gps_changed = false;               // the previous point of this context changed time

  static Fields14 from(const std::uint8_t* p) {
    Fields14 f;
    f.x = load_le<std::int32_t>(p);
    f.y = load_le<std::int32_t>(p + 4);
    f.z = load_le<std::int32_t>(p + 8);
    f.intensity = load_le<std::uint16_t>(p + 12);
    f.r = p[14] & 15u;
    f.n = p[14] >> 4;
    f.class_flags = p[15] & 15u;
    f.channel = (p[15] >> 4) & 3u;
    f.direction = (p[15] >> 6) & 1u;
    f.edge = p[15] >> 7;
    f.classification = p[16];
    f.user_data = p[17];
    f.scan_angle = load_le<std::int16_t>(p + 18);
    f.source = load_le<std::uint16_t>(p + 20);
    f.gps = load_le<std::int64_t>(p + 22);
    return f;
  }
  void to(std::uint8_t* p) const {
    store_le(p, x);
    store_le(p + 4, y);
    store_le(p + 8, z);
    store_le(p + 12, intensity);
    p[14] = static_cast<std::uint8_t>(r | (n << 4));
    p[15] = static_cast<std::uint8_t>(class_flags | (channel << 4) | (direction << 6) | (edge << 7));
    p[16] = static_cast<std::uint8_t>(classification);
    p[17] = static_cast<std::uint8_t>(user_data);
    store_le(p + 18, scan_angle);
    store_le(p + 20, source);
    store_le(p + 22, gps);
  }
};

/// Lazily created models, one per context value.
template <std::size_t N>
class Bank {
 public:
  explicit Bank(std::uint32_t symbols) : symbols_(symbols) {}
  SymbolModel& at(std::size_t i) {
    if (!m_[i]) m_[i] = std::make_unique<SymbolModel>(symbols_);
    return *m_[i];
  }

 private:
  std::uint32_t symbols_;
  std::array<std::unique_ptr<SymbolModel>, N> m_;
};

/// A layer: its own arithmetic decoder, and whether it carries data in this chunk.
struct Layer {
  ArithDecoder d;
  bool present = false;
};

void open_layers(std::vector<Layer>& layers, const std::vector<const std::uint8_t*>& data,
                 const std::vector<std::size_t>& sizes, bool first_always) {
  for (std::size_t i = 0; i < layers.size(); ++i) {
    layers[i].present = sizes[i] > 0 || (i == 0 && first_always);
    if (layers[i].present) layers[i].d.start(data[i], data[i] + sizes[i]);
  }
}

std::size_t layers_overrun(const std::vector<Layer>& layers) {
  std::size_t n = 0;
  for (const Layer& l : layers) n += l.present ? l.d.overrun() : 0;
  return n;
}

/// The per-scanner-channel state of POINT14.
struct Channel14 {
  explicit Channel14(const Fields14& seed) : last(seed) {
    last.gps_changed = false;
    for (auto& v : last_intensity) v = seed.intensity;
    for (auto& v : last_z) v = seed.z;
    gps.seed(seed.gps);
  }
  Fields14 last;
  std::uint16_t last_intensity[8];
  Median5 dx_median[12], dy_median[12];
  std::int32_t last_z[8];
  SymbolModel changed[8] = {SymbolModel(128), SymbolModel(128), SymbolModel(128), SymbolModel(128),
                            SymbolModel(128), SymbolModel(128), SymbolModel(128), SymbolModel(128)};
  SymbolModel channel_step{3};
  Bank<16> n_model{16}, r_model{16};
  SymbolModel r_same{13};
  IntDecoder dx{32, 2}, dy{32, 22}, z{32, 20};
  Bank<64> class_model{256}, flags_model{64}, user_model{256};
  IntDecoder intensity{16, 4}, angle{16, 2}, source{16, 1};
  GpsTimeDecoder gps{true};
};

class Point14 final : public LayeredItem {
 public:
  std::size_t layer_count() const override { return 9; }
  void start(const std::vector<const std::uint8_t*>& data, const std::vector<std::size_t>& sizes,
             const std::uint8_t* raw, std::uint32_t context) override {
    layers_.resize(9);
    open_layers(layers_, data, sizes, true);
    const Fields14 first = Fields14::from(raw);
    current_ = context & 3u;
    channels_[current_] = std::make_unique<Channel14>(first);
  }
  std::size_t overrun() const override { return layers_overrun(layers_); }

  void decode(std::uint8_t* out, std::uint32_t& context) override {
    Channel14* c = channels_[current_].get();
    ArithDecoder& xy = layers_[0].d;
    const std::uint32_t lpr = (c->last.r == 1 ? 1u : 0u) + (c->last.r >= c->last.n ? 2u : 0u) +
                              (c->last.gps_changed ? 4u : 0u);
    const std::uint32_t changed = xy.symbol(c->changed[lpr]);
    if (changed & 64) {
      const std::uint32_t next = (current_ + xy.symbol(c->channel_step) + 1) & 3u;
      if (!channels_[next]) channels_[next] = std::make_unique<Channel14>(c->last);
      current_ = next;
      context = next;
      c = channels_[next].get();
      c->last.channel = next;
    }
    const bool source_changed = changed & 32, gps_changed = changed & 16, angle_changed = changed & 8;
    Fields14& p = c->last;
    const std::uint32_t last_r = p.r;
    if (changed & 4) p.n = xy.symbol(c->n_model.at(p.n));
    switch (changed & 3) {
      case 0: break;
      case 1: p.r = (last_r + 1) & 15u; break;
      case 2: p.r = (last_r + 15) & 15u; break;
      default:
        p.r = gps_changed ? xy.symbol(c->r_model.at(last_r)) : (last_r + xy.symbol(c->r_same) + 2) & 15u;
        break;
    }
    const std::uint32_t n = p.n, r = p.r;
    const std::uint32_t m = kReturnClass16[n][r];
    const std::uint32_t spread = n > r ? n - r : r - n;
    const std::uint32_t l = spread < 7 ? spread : 7;
    const std::uint32_t cpr = (r == 1 ? 2u : 0u) + (r >= n ? 1u : 0u);
    const std::uint32_t slot = (m << 1) | (gps_changed ? 1u : 0u);

    const std::int32_t dx = c->dx.decode(xy, c->dx_median[slot].get(), n == 1);
    p.x = wrap_add(p.x, dx);
    c->dx_median[slot].add(dx);
    const std::uint32_t kx = c->dx.last_k();
    const std::int32_t dy = c->dy.decode(xy, c->dy_median[slot].get(), (n == 1) + (kx < 20 ? even_index(kx) : 20));
    p.y = wrap_add(p.y, dy);
    c->dy_median[slot].add(dy);
    if (layers_[1].present) {
      const std::uint32_t kz = (c->dx.last_k() + c->dy.last_k()) / 2;
      p.z = c->z.decode(layers_[1].d, c->last_z[l], (n == 1) + (kz < 18 ? even_index(kz) : 18));
      c->last_z[l] = p.z;
    }
    if (layers_[2].present) {
      const std::uint32_t ctx = ((p.classification & 31u) << 1) + (cpr == 3 ? 1u : 0u);
      p.classification = layers_[2].d.symbol(c->class_model.at(ctx));
    }
    if (layers_[3].present) {
      const std::uint32_t prev = (p.edge << 5) | (p.direction << 4) | p.class_flags;
      const std::uint32_t f = layers_[3].d.symbol(c->flags_model.at(prev));
      p.edge = (f >> 5) & 1u;
      p.direction = (f >> 4) & 1u;
      p.class_flags = f & 15u;
    }
    if (layers_[4].present) {
      const std::uint32_t s = (cpr << 1) | (gps_changed ? 1u : 0u);
      c->last_intensity[s] = static_cast<std::uint16_t>(c->intensity.decode(layers_[4].d, c->last_intensity[s], cpr));
      p.intensity = c->last_intensity[s];
    }
    if (layers_[5].present && angle_changed) {
      p.scan_angle = static_cast<std::int16_t>(c->angle.decode(layers_[5].d, p.scan_angle, gps_changed ? 1 : 0));
    }
    if (layers_[6].present) p.user_data = layers_[6].d.symbol(c->user_model.at(p.user_data / 4));
    if (layers_[7].present && source_changed) {
      p.source = static_cast<std::uint16_t>(c->source.decode(layers_[7].d, p.source, 0));
    }
    if (layers_[8].present && gps_changed) {
      c->gps.decode(layers_[8].d);
      p.gps = c->gps.value();
    }
    p.to(out);
    p.gps_changed = gps_changed;
  }

 private:
  std::vector<Layer> layers_;
  std::array<std::unique_ptr<Channel14>, 4> channels_;
  std::uint32_t current_ = 0;
};

/// Context bookkeeping shared by the items after POINT14: a context is created on first use
/// from the last values of the context used before; on the point that switches to an already
/// used context the previous context's last values still predict (and receive the result),
/// from the next point on the context's own (LASzip's behaviour, kept for exactness).
template <class State>
class ContextSet {
 public:
  void reset(std::uint32_t context, const State& seed) {
    for (auto& s : states_) s.reset();
    current_ = context & 3u;
    states_[current_] = std::make_unique<State>(seed);
  }
  /// The state to decode with for a point handed `context`, and in `last` the values that
  /// predict it.
  State& select(std::uint32_t context, typename State::Last*& last) {
    context &= 3u;
    last = &states_[current_]->last;
    if (context != current_) {
      current_ = context;
      if (!states_[context]) {
        states_[context] = std::make_unique<State>(State(*last));
        last = &states_[context]->last;
      }
    }
    return *states_[current_];
  }

 private:
  std::array<std::unique_ptr<State>, 4> states_;
  std::uint32_t current_ = 0;
};

struct RgbState {
  struct Last {
    std::uint16_t v[4] = {0, 0, 0, 0};  // R G B (NIR)
  };
  explicit RgbState(const Last& seed) : last(seed) {}
  Last last;
  SymbolModel used{128};
  SymbolModel diff[6] = {SymbolModel(256), SymbolModel(256), SymbolModel(256),
                         SymbolModel(256), SymbolModel(256), SymbolModel(256)};
  SymbolModel nir_used{4};
  SymbolModel nir_diff[2] = {SymbolModel(256), SymbolModel(256)};
};

class Rgb14 final : public LayeredItem {
 public:
  explicit Rgb14(bool nir) : nir_(nir) {}
  std::size_t layer_count() const override { return nir_ ? 2 : 1; }
  void start(const std::vector<const std::uint8_t*>& data, const std::vector<std::size_t>& sizes,
             const std::uint8_t* raw, std::uint32_t context) override {
    layers_.resize(layer_count());
    open_layers(layers_, data, sizes, false);
    RgbState::Last seed;
    std::memcpy(seed.v, raw, nir_ ? 8 : 6);
    contexts_.reset(context, RgbState(seed));
  }
  std::size_t overrun() const override { return layers_overrun(layers_); }
  void decode(std::uint8_t* out, std::uint32_t& context) override {
    RgbState::Last* prev = nullptr;
    RgbState& s = contexts_.select(context, prev);
    std::uint16_t* last = prev->v;
    std::uint16_t v[4];
    if (layers_[0].present) {
      decode_rgb(layers_[0].d, s.used, s.diff, last, v);
      std::memcpy(last, v, 6);
    } else {
      std::memcpy(v, last, 6);
    }
    if (nir_) {
      if (layers_[1].present) {
        ArithDecoder& d = layers_[1].d;
        const std::uint32_t used = d.symbol(s.nir_used);
        std::uint32_t lo = last[3] & 0xFFu, hi = last[3] >> 8;
        if (used & 1) lo = (d.symbol(s.nir_diff[0]) + lo) & 0xFFu;
        if (used & 2) hi = (d.symbol(s.nir_diff[1]) + hi) & 0xFFu;
        last[3] = static_cast<std::uint16_t>(lo | (hi << 8));
      }
      v[3] = last[3];
    }
    std::memcpy(out, v, nir_ ? 8 : 6);
  }

 private:
  bool nir_;
  std::vector<Layer> layers_;
  ContextSet<RgbState> contexts_;
};

struct ByteState {
  struct Last {
    std::vector<std::uint8_t> v;
  };
  explicit ByteState(const Last& seed) : last(seed), models(seed.v.size(), SymbolModel(256)) {}
  Last last;
  std::vector<SymbolModel> models;
};

class Byte14 final : public LayeredItem {
 public:
  explicit Byte14(std::size_t n) : n_(n) {}
  std::size_t layer_count() const override { return n_; }
  void start(const std::vector<const std::uint8_t*>& data, const std::vector<std::size_t>& sizes,
             const std::uint8_t* raw, std::uint32_t context) override {
    layers_.resize(n_);
    open_layers(layers_, data, sizes, false);
    ByteState::Last seed;
    seed.v.assign(raw, raw + n_);
    contexts_.reset(context, ByteState(seed));
  }
  std::size_t overrun() const override { return layers_overrun(layers_); }
  void decode(std::uint8_t* out, std::uint32_t& context) override {
    ByteState::Last* prev = nullptr;
    ByteState& s = contexts_.select(context, prev);
    std::vector<std::uint8_t>& last = prev->v;
    for (std::size_t i = 0; i < n_; ++i) {
      if (layers_[i].present) last[i] = static_cast<std::uint8_t>(last[i] + layers_[i].d.symbol(s.models[i]));
      out[i] = last[i];
    }
  }

 private:
  std::size_t n_;
  std::vector<Layer> layers_;
  ContextSet<ByteState> contexts_;
};

}  // namespace

std::unique_ptr<LayeredItem> make_layered_item(const Item& item) {
  if (item.version != 3) return nullptr;
  switch (item.type) {
    case kPoint14: return item.size == 30 ? std::make_unique<Point14>() : nullptr;
    case kRgb14: return item.size == 6 ? std::make_unique<Rgb14>(false) : nullptr;
    case kRgbNir14: return item.size == 8 ? std::make_unique<Rgb14>(true) : nullptr;
    case kByte14: return item.size > 0 ? std::make_unique<Byte14>(item.size) : nullptr;
    default: return nullptr;
  }
}

}  // namespace hc::pipeline::detail::laz
