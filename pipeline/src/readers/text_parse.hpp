#pragma once
/// @file text_parse.hpp
/// Small text helpers shared by the scan readers and load_cloud (private to the pipeline).

#include "hc/pipeline/cloud.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

namespace hc::pipeline::detail {

/// 'path' in single quotes, for messages.
inline std::string quoted(const std::filesystem::path& p) {
  std::string s(1, '\'');  // built by appending: GCC 12 -O3 flags "'" + str + "'" (-Wrestrict)
  s += p.string();
  s += '\'';
  return s;
}

inline std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

/// Separators of the text formats: blanks and commas.
inline bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f' || c == ','; }

/// Parses one number (double or float) starting at p, after skipping separators; advances p.
/// false if there is no number, it is out of range, or it runs into other characters ("1.5abc").
template <class T>
bool parse_number(const char*& p, const char* end, T& value) {
  while (p < end && is_space(*p)) ++p;
  if (p >= end) return false;
  const char* start = p;
  if (*start == '+') {  // from_chars rejects a leading '+'
    ++start;
    if (start < end && (*start == '-' || *start == '+')) return false;  // "+-1" is no number
  }
  const auto res = std::from_chars(start, end, value);
  if (res.ec != std::errc()) return false;
  if (res.ptr < end && !is_space(*res.ptr)) return false;
  p = res.ptr;
  return true;
}

inline bool parse_double(const char*& p, const char* end, double& value) { return parse_number(p, end, value); }

/// The token at p (after separators), for messages.
inline std::string_view first_token(const char* p, const char* end) {
  while (p < end && is_space(*p)) ++p;
  const char* q = p;
  while (q < end && !is_space(*q)) ++q;
  return {p, static_cast<std::size_t>(q - p)};
}

/// Checks that [b, e) holds exactly `expected` numbers; returns a description of the first
/// problem, or an empty string.
inline std::string check_numeric_line(const char* b, const char* e, std::size_t expected) {
  std::size_t found = 0;
  const char* p = b;
  for (;;) {
    while (p < e && is_space(*p)) ++p;
    if (p >= e) break;
    const char* t = p;
    double v = 0.0;
    if (!parse_double(p, e, v)) {
      std::string problem(1, '\'');  // built by appending: GCC 12 -O3 flags "'" + str (-Wrestrict)
      problem += first_token(t, e).substr(0, 40);
      problem += "' is not a number";
      return problem;
    }
    ++found;
  }
  if (found != expected) {
    return std::to_string(found) + " values where the header declares " + std::to_string(expected);
  }
  return {};
}

/// Header line reader shared by the PLY and PCD header parsers: copies the line that starts at
/// `pos` into `line` (without its '\n' and a trailing '\r') and moves `pos` past it. Returns
/// false when no line is left; an unterminated last line counts only if accept_unterminated.
inline bool next_line(const std::string& raw, std::size_t& pos, std::string& line, bool accept_unterminated) {
  if (pos >= raw.size()) return false;
  std::size_t nl = raw.find('\n', pos);
  if (nl == std::string::npos) {
    if (!accept_unterminated) return false;
    nl = raw.size();
  }
  line.assign(raw, pos, nl - pos);
  pos = nl + 1;
  if (!line.empty() && line.back() == '\r') line.pop_back();
  return true;
}

/// A Cloud from interleaved x, y, z values.
inline Cloud cloud_from(const std::vector<double>& xyz) {
  Cloud c;
  c.xyz = Eigen::Map<const Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(xyz.size() / 3));
  return c;
}

}  // namespace hc::pipeline::detail
