// Fuzz target: bytes from the USB link through the Falcon frame assembler (hc/falcon/protocol.hpp),
// in chunks of varying size, in both directions. Besides "no crash", it checks the assembler's
// contract: every frame it hands out decodes, and re-encodes to the same bytes (all but byte 14,
// a reserved field that decoding accepts in 'A'..'P' and encoding writes as 'A').
#include "../fuzz_support.hpp"

#include "hc/falcon/protocol.hpp"

#include <algorithm>
#include <cstdlib>
#include <span>

namespace hc::fuzz {
namespace {

bool same_but_reserved(falcon::Frame a, falcon::Frame b) {
  a[14] = b[14] = 0;
  return a == b;
}

}  // namespace

void falcon_frames(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return;
  const bool from_host = (data[0] & 1) != 0;
  const std::size_t chunk = 1 + data[1] % 64;  // reads of 1..64 bytes, like USB transfers
  falcon::FrameAssembler assembler(from_host ? falcon::FrameAssembler::Direction::kFromHost
                                             : falcon::FrameAssembler::Direction::kFromDevice);
  std::uint64_t completed = 0;
  for (std::size_t at = 2; at < size; at += chunk) {
    const std::size_t n = std::min(chunk, size - at);
    completed += assembler.push(std::span<const std::uint8_t>(data + at, n));
    falcon::Frame f;
    if (!assembler.take(f)) continue;
    if (from_host) {
      falcon::CommandFrame c;
      if (!falcon::decode_command(f, c)) std::abort();  // handed out a frame that does not decode
      if (!same_but_reserved(falcon::encode_command(c), f)) std::abort();
    } else {
      falcon::StatusFrame s;
      if (!falcon::decode_status(f, s)) std::abort();
      if (!same_but_reserved(falcon::encode_status(s), f)) std::abort();
    }
  }
  if (completed != assembler.good_frames()) std::abort();
}

}  // namespace hc::fuzz
