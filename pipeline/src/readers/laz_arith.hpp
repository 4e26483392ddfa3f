#pragma once
/// @file laz_arith.hpp
/// The entropy decoder of LAZ (LASzip) point data: a 32-bit range (arithmetic) decoder with
/// adaptive binary and multi-symbol models, and the "integer compressor" that codes a value as
/// a corrector to a prediction (bucket k = bit length of the corrector, then the corrector's
/// bits). Written clean room from the published descriptions (LASzip specification and
/// M. Isenburg, "LASzip: lossless compression of
/// LiDAR data", PE&RS 79(2), 2013; the coder is A. Said's "FastAC", HP Labs report
/// HPL-2004-76), with constants checked against LASzip's decoder as facts. Facts followed
/// (no code carried over):
///   - interval: 32-bit `length`, renormalised by bytes while length < 2^24; the decoder
///     starts with 4 big-endian bytes in `value` and length 2^32 − 1;
///   - binary model: probability of 0 in 13 bits, counts halved above 2^13, the update period
///     starts at 4 and grows ×5/4 up to 64 symbols;
///   - multi-symbol model: cumulative distribution in 15 bits, counts halved above 2^15, the
///     update period starts at (n + 6)/2 and grows ×5/4 up to 8·(n + 6); models of more than
///     16 symbols are decoded with a division and a lookup table (LASzip: 2^b entries, b from 3
///     while n > 2^(b+2)); the table is only the decoder's search aid (the symbol is fixed by
///     the cumulative counts), so this decoder sizes it differently (2^b ≥ n), fills it in its
///     own way (slot j: the largest symbol at or below the slot's first target) and walks up
///     from it; smaller models are searched by halving the symbol range;
///   - raw bits: up to 19 bits at once from the interval, wider values as 16-bit halves
///     (low half first);
///   - integer compressor: correctors of `bits` bits (range 2^bits, wrapped into it); bucket
///     model per context with bits + 1 symbols; bucket 0 codes {0, 1} with a binary model;
///     bucket k ≤ bits_high (8) codes the k-bit corrector with a 2^k-symbol model; above, the
///     top bits_high bits by model and the k − bits_high low bits raw; a k-bit code c maps to
///     c + 1 if c ≥ 2^(k−1), else c − (2^k − 1); bucket 32 is the minimum integer.
///
/// Safety: the decoder reads only inside its [begin, end) buffer; past the end it feeds zero
/// bytes and counts them, and `overrun()` tells the caller the stream was too short (a
/// truncated or corrupt chunk), so no input makes it read out of bounds, divide by zero or
/// loop forever.

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <vector>

namespace hc::pipeline::detail::laz {

/// Adaptive model of one binary decision.
class BitModel {
 public:
  BitModel() = default;

 private:
  friend class ArithDecoder;
  // Out of line: runs once per update period, and keeping it out of the symbol path keeps
  // that path small enough to inline into the item decoders.
  [[gnu::noinline]] void refresh() {
    count_total_ += period_;
    if (count_total_ > kMaxCount) {
      count_total_ = (count_total_ + 1) >> 1;
      count_zero_ = (count_zero_ + 1) >> 1;
      if (count_zero_ == count_total_) ++count_total_;
    }
    const std::uint32_t unit = 0x80000000u / count_total_;
    p_zero_ = (count_zero_ * unit) >> (31 - kShift);
    period_ = (5 * period_) >> 2;
    if (period_ > 64) period_ = 64;
    countdown_ = period_;
  }
  static constexpr std::uint32_t kShift = 13;
  static constexpr std::uint32_t kMaxCount = 1u << kShift;
  std::uint32_t count_zero_ = 1, count_total_ = 2;
  std::uint32_t p_zero_ = 1u << (kShift - 1);
  std::uint32_t period_ = 4, countdown_ = 4;
};

/// Adaptive model of a symbol in [0, n), 2 ≤ n ≤ 2^11.
class SymbolModel {
 public:
  explicit SymbolModel(std::uint32_t n = 2) { reset(n); }
  void reset(std::uint32_t n) {
    n_ = n;
    counts_.assign(n, 1u);
    cdf_.assign(n + 1, 0u);
    cdf_[n] = 0xFFFFFFFFu;  // sentinel of the decoder's walk (above any target; never a bound)
    if (n > 16) {
      std::uint32_t bits = 3;
      // About one table entry per symbol (LASzip: one per four). The table only narrows the
      // search; measured on the Autzen LAZ, 1 per symbol costs the fewest instructions (finer
      // ones cost more in refresh() than the shorter walk saves).
      while (n > (1u << bits)) ++bits;
      table_size_ = 1u << bits;
      table_shift_ = kShift - bits;
      table_.assign(table_size_ + 2, 0u);
    } else {
      table_size_ = 0;
      table_shift_ = 0;
      table_.clear();
    }
    total_ = 0;
    period_ = n;
    refresh();
    period_ = (n + 6) >> 1;
    countdown_ = period_;
  }
  std::uint32_t size() const { return n_; }

 private:
  friend class ArithDecoder;
  [[gnu::noinline]] void refresh() {  // out of line, as BitModel::refresh
    total_ += period_;
    if (total_ > kMaxCount) {
      total_ = 0;
      for (auto& c : counts_) {
        c = (c + 1) >> 1;
        total_ += c;
      }
    }
    const std::uint32_t unit = 0x80000000u / total_;
    // Locals, not members, in the loops: the stores into the uint32 arrays could alias the
    // uint32 members, which would make the compiler reload them on every iteration.
    const std::uint32_t n = n_, shift = table_shift_, size = table_size_;
    const std::uint32_t* counts = counts_.data();
    std::uint32_t* cdf = cdf_.data();
    std::uint32_t running = 0;
    for (std::uint32_t s = 0; s < n; ++s) {
      cdf[s] = (unit * running) >> (31 - kShift);
      running += counts[s];
    }
    if (size != 0) {
      // Search aid: slot j names the largest symbol whose cumulative value is at most the
      // slot's first target j·2^shift, so it lies at or below the symbol of any target in the
      // slot; the decoder walks up from it. One merge pass over slots and symbols.
      std::uint32_t* table = table_.data();
      std::uint32_t sym = 0;
      for (std::uint32_t j = 0; j <= size; ++j) {
        const std::uint32_t first_target = j << shift;
        while (sym + 1 < n && cdf[sym + 1] <= first_target) ++sym;
        table[j] = sym;
      }
    }
    period_ = (5 * period_) >> 2;
    const std::uint32_t longest = (n_ + 6) << 3;
    if (period_ > longest) period_ = longest;
    countdown_ = period_;
  }
  static constexpr std::uint32_t kShift = 15;
  static constexpr std::uint32_t kMaxCount = 1u << kShift;
  std::uint32_t n_ = 0;
  std::vector<std::uint32_t> counts_, cdf_, table_;
  std::uint32_t table_size_ = 0, table_shift_ = 0;
  std::uint32_t total_ = 0, period_ = 0, countdown_ = 0;
};

/// Range decoder over one byte buffer.
class ArithDecoder {
 public:
  ArithDecoder() = default;
  /// Starts decoding at `begin` (reads the first 4 bytes). Bytes past `end` read as 0.
  void start(const std::uint8_t* begin, const std::uint8_t* end) {
    at_ = begin;
    end_ = end;
    missing_ = 0;
    length_ = 0xFFFFFFFFu;
    value_ = 0;
    for (int i = 0; i < 4; ++i) value_ = (value_ << 8) | next_byte();
  }
  /// Number of bytes requested past the end of the buffer. The encoder's flush leaves the last
  /// bytes the decoder needs inside the stream, so a valid stream keeps this at 0; more than a
  /// few means a truncated or corrupt stream.
  std::size_t overrun() const { return missing_; }

  [[gnu::always_inline]] std::uint32_t bit(BitModel& m) {
    const std::uint32_t split = m.p_zero_ * (length_ >> BitModel::kShift);
    std::uint32_t out;
    if (value_ < split) {
      out = 0;
      length_ = split;
      ++m.count_zero_;
    } else {
      out = 1;
      value_ -= split;
      length_ -= split;
    }
    if (length_ < kMinLength) renormalise();
    if (--m.countdown_ == 0) m.refresh();
    return out;
  }

  /// The next symbol of model m. kTable: the caller knows m has more than 16 symbols (so a
  /// decoding table), which spares the test.
  template <bool kTable = false>
  [[gnu::always_inline]] std::uint32_t symbol(SymbolModel& m) {
    std::uint32_t s, lo, hi = length_;
    if (kTable || m.table_size_ != 0) {
      length_ >>= SymbolModel::kShift;
      const std::uint32_t target = value_ / length_;
      std::uint32_t t = target >> m.table_shift_;
      if (t > m.table_size_) t = m.table_size_;  // only reachable from corrupt input
      // The table gives a symbol at or below the answer, usually the answer or a step below
      // (measured: fewer instructions than a bisection up to table_[t + 1], or than one step
      // then a bisection); cdf_[n_] = 2^32 − 1, above any target, stops the walk.
      const std::uint32_t* cdf = m.cdf_.data();
      s = m.table_[t];
      while (cdf[s + 1] <= target) ++s;
      lo = cdf[s] * length_;
      if (s + 1 != m.n_) hi = cdf[s + 1] * length_;
    } else {
      // Few symbols: the symbol is the largest s with cdf[s]·length ≤ value (cdf[0] = 0);
      // halve the candidate range [first, past) until one symbol is left.
      length_ >>= SymbolModel::kShift;
      const std::uint32_t* cdf = m.cdf_.data();
      std::uint32_t first = 0, past = m.n_;
      while (past - first > 1) {
        const std::uint32_t probe = first + ((past - first) >> 1);
        if (cdf[probe] * length_ <= value_) {
          first = probe;
        } else {
          past = probe;
        }
      }
      s = first;
      lo = cdf[s] * length_;
      if (s + 1 != m.n_) hi = cdf[s + 1] * length_;
    }
    value_ -= lo;
    length_ = hi - lo;
    if (length_ < kMinLength) renormalise();
    ++m.counts_[s];
    if (--m.countdown_ == 0) m.refresh();
    return s;
  }

  /// `n` raw bits (0 < n ≤ 32), low half first when n > 19.
  [[gnu::always_inline]] std::uint32_t bits(std::uint32_t n) {
    if (n > 19) {
      const std::uint32_t low = short16();
      const std::uint32_t high = few_bits(n - 16);
      return (high << 16) | low;
    }
    return few_bits(n);
  }
  [[gnu::always_inline]] std::uint32_t short16() { return few_bits(16); }
  [[gnu::always_inline]] std::uint32_t int32() {
    const std::uint32_t low = short16();
    const std::uint32_t high = short16();
    return (high << 16) | low;
  }

 private:
  static constexpr std::uint32_t kMinLength = 0x01000000u;
  /// `n` ≤ 19 raw bits.
  [[gnu::always_inline]] std::uint32_t few_bits(std::uint32_t n) {
    length_ >>= n;
    const std::uint32_t s = value_ / length_;
    value_ -= length_ * s;
    if (length_ < kMinLength) renormalise();
    return s;
  }
  [[gnu::always_inline]] std::uint32_t next_byte() {
    if (at_ < end_) return *at_++;
    ++missing_;
    return 0;
  }
  [[gnu::always_inline]] void renormalise() {
    if (length_ == 0) length_ = 1;  // corrupt input only: keeps the loop finite
    do {
      value_ = (value_ << 8) | next_byte();
      length_ <<= 8;
    } while (length_ < kMinLength);
  }
  const std::uint8_t* at_ = nullptr;
  const std::uint8_t* end_ = nullptr;
  std::size_t missing_ = 0;
  std::uint32_t value_ = 0, length_ = 0;
};

/// Integer compressor (decoding side): value = prediction + corrector, wrapped into the
/// corrector range; `contexts` independent bucket models.
class IntDecoder {
 public:
  /// `bits` 16 to 32 (LAZ uses 16 and 32; 0 means 32), so every bucket model has a table.
  IntDecoder(std::uint32_t bits = 16, std::uint32_t contexts = 1) {
    if (bits != 0 && (bits < 16 || bits > 32)) throw std::logic_error("laz::IntDecoder: bits must be 16 to 32");
    if (bits > 0 && bits < 32) {
      corr_bits_ = bits;
      range_ = 1u << bits;
      min_ = -static_cast<std::int64_t>(range_ / 2);
    } else {
      corr_bits_ = 32;
      range_ = 0;
      min_ = INT32_MIN;
    }
    buckets_.assign(contexts, SymbolModel(corr_bits_ + 1));
    small_.resize(corr_bits_ + 1);
    for (std::uint32_t k = 1; k <= corr_bits_; ++k) small_[k].reset(1u << (k <= kBitsHigh ? k : kBitsHigh));
  }
  /// Resets every model to its initial state (start of a chunk).
  void reset() {
    for (auto& b : buckets_) b.reset(corr_bits_ + 1);
    zero_ = BitModel();
    for (std::uint32_t k = 1; k <= corr_bits_; ++k) small_[k].reset(1u << (k <= kBitsHigh ? k : kBitsHigh));
  }
  /// The value predicted by `pred` and coded in `context` (< contexts).
  /// Inlined into the item decoders (a few call sites each), which saves the call overhead on
  /// the hottest path of the decoder.
  [[gnu::always_inline]] std::int32_t decode(ArithDecoder& d, std::int32_t pred, std::uint32_t context) {
    const std::int32_t c = corrector(d, buckets_[context]);
    std::uint32_t v = static_cast<std::uint32_t>(pred) + static_cast<std::uint32_t>(c);
    if (range_ != 0) {
      // Wrap into [0, range) the way a two's-complement sum of a `bits`-bit field does.
      const std::int64_t sv = static_cast<std::int64_t>(pred) + c;
      std::int64_t w = sv;
      if (w < 0) w += range_;
      else if (w >= static_cast<std::int64_t>(range_)) w -= range_;
      v = static_cast<std::uint32_t>(w);
    }
    return static_cast<std::int32_t>(v);
  }
  /// The bucket (bit length of the corrector) of the last decode; contexts of later fields.
  std::uint32_t last_k() const { return k_; }

 private:
  [[gnu::always_inline]] std::int32_t corrector(ArithDecoder& d, SymbolModel& bucket) {
    k_ = d.symbol<true>(bucket);
    if (k_ == 0) return static_cast<std::int32_t>(d.bit(zero_));
    if (k_ >= 32) return static_cast<std::int32_t>(min_);
    std::uint32_t code;
    if (k_ <= kBitsHigh) {
      code = d.symbol(small_[k_]);
    } else {
      const std::uint32_t low_bits = k_ - kBitsHigh;
      code = (d.symbol(small_[k_]) << low_bits) | d.bits(low_bits);
    }
    // In 32-bit unsigned arithmetic; the conversion to int32 wraps (C++20), as the corrector's
    // two's-complement definition does.
    if (code >= (1u << (k_ - 1))) return static_cast<std::int32_t>(code + 1);
    return static_cast<std::int32_t>(code - ((1u << k_) - 1));
  }
  static constexpr std::uint32_t kBitsHigh = 8;  // bits_high of the LAZ integer compressor
  std::uint32_t corr_bits_ = 16, range_ = 0;
  std::int64_t min_ = 0;
  std::vector<SymbolModel> buckets_;
  BitModel zero_;
  std::vector<SymbolModel> small_;
  std::uint32_t k_ = 0;
};

}  // namespace hc::pipeline::detail::laz
