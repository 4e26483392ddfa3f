#pragma once
/// @file app_runner.hpp
/// Runs the `hapticloud` program under test (its path is the HC_APP compile definition of the
/// integration suites) and reads what it wrote.

#include <nlohmann/json.hpp>

#include <sys/wait.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace hc::test {

/// Runs `hapticloud ARGS` through the shell, appends its stdout and stderr to *output and
/// returns its exit status (−1 if it could not be started or did not exit normally).
/// `env_prefix` goes before the program on the command line (e.g. "env -u X Y=1 ").
inline int run_app(const std::string& args, std::string* output, const std::string& env_prefix = "") {
  const std::string cmd = env_prefix + std::string(HC_APP) + " " + args + " 2>&1";
  std::FILE* p = popen(cmd.c_str(), "r");
  if (!p) return -1;
  char buf[4096];
  while (std::fgets(buf, sizeof buf, p)) *output += buf;
  const int raw = pclose(p);
  return WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
}

/// Parses a JSON file (throws nlohmann::json::parse_error on bad JSON).
inline nlohmann::json read_json(const std::filesystem::path& f) {
  std::ifstream in(f);
  return nlohmann::json::parse(in);
}

/// True when the file starts with the 8-byte PNG signature.
inline bool is_png(const std::filesystem::path& f) {
  std::ifstream in(f, std::ios::binary);
  char sig[8] = {};
  in.read(sig, 8);
  return in && std::string(sig, 8) == "\x89PNG\r\n\x1a\n";
}

}  // namespace hc::test
