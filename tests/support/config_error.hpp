#pragma once
/// @file config_error.hpp
/// The message of the error a run configuration raises, for the config tests.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"

#include <string>
#include <vector>

namespace hc::test {

/// Parses `yaml` as the run configuration "configs/test.yaml" with `--set` overrides `sets`;
/// returns the hc::Error's message, or "" when it parses.
inline std::string config_error(const std::string& yaml, const std::vector<std::string>& sets = {}) {
  try {
    pipeline::parse_run_config(yaml, "configs/test.yaml", sets);
  } catch (const hc::Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace hc::test
