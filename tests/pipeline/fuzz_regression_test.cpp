// Replays every saved fuzz input — the seed corpora (tests/fuzz/corpus/TARGET) and the inputs
// that once crashed a reader (tests/fuzz/regressions/TARGET) — through the same public readers
// the libFuzzer targets call (tests/fuzz/targets). Each input must be read or refused with an
// hc::Error (the target swallows those); any other exception fails the test, and a crash or a
// sanitizer report (asan preset) ends it. Issue 15.

#include "fuzz_support.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <typeinfo>
#include <vector>

namespace {

namespace fs = std::filesystem;

std::vector<fs::path> inputs_in(const fs::path& dir) {
  std::vector<fs::path> files;
  if (!fs::is_directory(dir)) return files;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.is_regular_file()) files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

std::vector<std::uint8_t> bytes_of(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class FuzzInputs : public ::testing::TestWithParam<hc::fuzz::Target> {};

TEST_P(FuzzInputs, EverySavedInputIsReadOrRefusedWithAnHcError) {
  const hc::fuzz::Target& target = GetParam();
  const fs::path dir = fs::path(HC_FUZZ_DIR);
  const auto seeds = inputs_in(dir / "corpus" / std::string(target.name));
  const auto regressions = inputs_in(dir / "regressions" / std::string(target.name));
  // Every target has a seed corpus; an empty one means the harness reads the wrong folder.
  ASSERT_FALSE(seeds.empty()) << "no seed in " << (dir / "corpus" / std::string(target.name));
  std::vector<fs::path> all = seeds;
  all.insert(all.end(), regressions.begin(), regressions.end());
  for (const fs::path& p : all) {
    const std::vector<std::uint8_t> data = bytes_of(p);
    ASSERT_EQ(data.size(), fs::file_size(p)) << p;
    try {
      target.run(data.data(), data.size());
    } catch (const std::exception& e) {
      ADD_FAILURE() << p << ": not an hc::Error but " << typeid(e).name() << ": " << e.what();
    } catch (...) {
      ADD_FAILURE() << p << ": a non-std exception";
    }
  }
  ::testing::Test::RecordProperty("inputs", std::to_string(all.size()));
}

INSTANTIATE_TEST_SUITE_P(Readers, FuzzInputs, ::testing::ValuesIn(hc::fuzz::all_targets()),
                         [](const ::testing::TestParamInfo<hc::fuzz::Target>& p) {
                           return std::string(p.param.name);
                         });

}  // namespace
