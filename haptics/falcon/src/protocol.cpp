// Run-mode frame codec of the Falcon (facts from libnifalcon (BSD), re-derived; see protocol.hpp).
#include "hc/falcon/protocol.hpp"

namespace hc::falcon {
namespace {

constexpr std::uint8_t kStart = '<';
constexpr std::uint8_t kEnd = '>';
constexpr std::uint8_t kBias = 0x41;

void put_axes(Frame& f, const std::array<std::int16_t, 3>& v) noexcept {
  for (std::size_t axis = 0; axis < 3; ++axis) {
    const auto bits = static_cast<std::uint16_t>(v[axis]);
    for (std::size_t k = 0; k < 4; ++k) {
      f[1 + 4 * axis + k] = static_cast<std::uint8_t>(kBias + ((bits >> (4 * k)) & 0xF));
    }
  }
}

// Fields are 'A' + v; nibble fields need v < 16, byte 13 v < 128.
bool body_ok(std::span<const std::uint8_t> b, unsigned byte13_limit) noexcept {
  if (b.size() != kFrameSize || b[0] != kStart || b[15] != kEnd) return false;
  for (std::size_t i = 1; i <= 12; ++i) {
    if (b[i] < kBias || b[i] >= kBias + 16) return false;
  }
  if (b[13] < kBias || static_cast<unsigned>(b[13] - kBias) >= byte13_limit) return false;
  return b[14] >= kBias && b[14] < kBias + 16;
}

std::array<std::int16_t, 3> get_axes(std::span<const std::uint8_t> b) noexcept {
  std::array<std::int16_t, 3> v{};
  for (std::size_t axis = 0; axis < 3; ++axis) {
    unsigned bits = 0;
    for (std::size_t k = 0; k < 4; ++k) bits |= static_cast<unsigned>(b[1 + 4 * axis + k] - kBias) << (4 * k);
    v[axis] = static_cast<std::int16_t>(static_cast<std::uint16_t>(bits));  // two's complement
  }
  return v;
}

}  // namespace

Frame encode_command(const CommandFrame& c) noexcept {
  Frame f{};
  f[0] = kStart;
  f[15] = kEnd;
  put_axes(f, c.motor);
  f[13] = static_cast<std::uint8_t>(kBias + ((c.leds & 0xE) | (c.homing ? 1 : 0)));
  f[14] = kBias;
  return f;
}

bool decode_command(std::span<const std::uint8_t> b, CommandFrame& out) noexcept {
  if (!body_ok(b, 16)) return false;
  out.motor = get_axes(b);
  const auto v = static_cast<std::uint8_t>(b[13] - kBias);
  out.leds = static_cast<std::uint8_t>(v & 0xE);
  out.homing = (v & 1) != 0;
  return true;
}

Frame encode_status(const StatusFrame& s) noexcept {
  Frame f{};
  f[0] = kStart;
  f[15] = kEnd;
  put_axes(f, s.encoder);
  f[13] = static_cast<std::uint8_t>(kBias + ((s.buttons & 0xF) | ((s.homed_mask & 0x7) << 4)));
  f[14] = kBias;
  return f;
}

bool decode_status(std::span<const std::uint8_t> b, StatusFrame& out) noexcept {
  if (!body_ok(b, 128)) return false;
  out.encoder = get_axes(b);
  const auto v = static_cast<std::uint8_t>(b[13] - kBias);
  out.buttons = static_cast<std::uint8_t>(v & 0xF);
  out.homed_mask = static_cast<std::uint8_t>((v >> 4) & 0x7);
  return true;
}

bool FrameAssembler::valid(const Frame& f) const noexcept {
  return body_ok(f, direction_ == Direction::kFromDevice ? 128U : 16U);
}

void FrameAssembler::push_byte(std::uint8_t b) noexcept {
  if (size_ == 0 && b != kStart) {
    ++skipped_;
    return;
  }
  pending_[size_++] = b;
  if (size_ < kFrameSize) return;
  if (valid(pending_)) {
    newest_ = pending_;
    has_newest_ = true;
    ++good_;
    size_ = 0;
    return;
  }
  // Not a frame: resynchronise at the next '<' after the bad start.
  ++bad_;
  std::size_t next = 1;
  while (next < kFrameSize && pending_[next] != kStart) ++next;
  skipped_ += next;
  for (std::size_t i = next; i < kFrameSize; ++i) pending_[i - next] = pending_[i];
  size_ = kFrameSize - next;
}

std::size_t FrameAssembler::push(std::span<const std::uint8_t> bytes) noexcept {
  const std::uint64_t before = good_;
  for (const std::uint8_t b : bytes) push_byte(b);
  return static_cast<std::size_t>(good_ - before);
}

bool FrameAssembler::take(Frame& out) noexcept {
  if (!has_newest_) return false;
  out = newest_;
  has_newest_ = false;
  return true;
}

void FrameAssembler::reset() noexcept {
  size_ = 0;
  has_newest_ = false;
}

}  // namespace hc::falcon
