#pragma once
/// @file error_of.hpp
/// The message of the hc::InputError a call throws, for tests that check what an error names.

#include "hc/common/error.hpp"

#include <exception>
#include <string>

namespace hc::test {

/// Runs f(); returns the hc::InputError's message, "WRONG EXCEPTION TYPE: ..." for any other
/// exception, or "NO EXCEPTION".
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const hc::InputError& e) {
    return e.what();
  } catch (const std::exception& e) {
    return std::string("WRONG EXCEPTION TYPE: ") + e.what();
  }
  return "NO EXCEPTION";
}

}  // namespace hc::test
