#pragma once
/// @file format.hpp
/// The project's one number formatter for error messages, reports, notes and labels.

#include <cstdio>
#include <string>

namespace hc {

/// How format_number writes a value.
enum class NumberStyle {
  kSignificant,  ///< `precision` significant digits, fixed or exponent, whichever is shorter
                 ///< (printf %.*g; the same text as an ostream with default flags)
  kFixed,        ///< `precision` digits after the decimal point (printf %.*f; std::fixed)
};

/// A double as text: format_number(0.000123) = "0.000123", format_number(1e7) = "1e+07",
/// format_number(2.5, 3, NumberStyle::kFixed) = "2.500"; NaN and infinities as "nan", "inf".
/// @param precision  significant digits (kSignificant, 1..17) or decimals (kFixed, 0..17);
///                   clamped to [0, 17].
/// Thread-safe: yes (no locale state beyond the C locale's decimal point).
inline std::string format_number(double v, int precision = 6, NumberStyle style = NumberStyle::kSignificant) {
  precision = precision < 0 ? 0 : precision > 17 ? 17 : precision;
  char buf[352];  // %.17f of the largest double needs 327 characters
  const int n = std::snprintf(buf, sizeof buf, style == NumberStyle::kFixed ? "%.*f" : "%.*g", precision, v);
  return n > 0 ? std::string(buf, static_cast<std::size_t>(n < static_cast<int>(sizeof buf) ? n : sizeof buf - 1))
               : std::string();
}

}  // namespace hc
