#pragma once
/// @file error.hpp
/// Exceptions thrown at hapticloud's public API, the pipeline, I/O and config loading.
/// Policy (see docs/architecture.md): a message names the file, the YAML key and line, the
/// offending value and what was expected. The servo loop never throws (status codes instead).

#include <stdexcept>
#include <string>

namespace hc {

/// Base of every hapticloud exception. Catch this in apps to print a one-line cause.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A file or its contents is missing, unreadable, truncated or not what was expected.
class InputError : public Error {
 public:
  using Error::Error;
};

/// A configuration key is unknown, of the wrong type or out of its allowed range.
class ConfigError : public Error {
 public:
  using Error::Error;
};

/// A request would exceed a configured resource cap (memory, cells); the message gives both the
/// requested and the allowed amount.
class ResourceError : public Error {
 public:
  using Error::Error;
};

/// The input is readable but degenerate for the requested operation (for example a cloud with
/// zero projected area, all points in one cell).
class DegenerateInputError : public InputError {
 public:
  using InputError::InputError;
};

}  // namespace hc
