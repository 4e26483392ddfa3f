#include "hc/falcon/firmware.hpp"

#include "falcon_test_support.hpp"
#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <cstdlib>

namespace hc::falcon {
namespace {

std::shared_ptr<FalconEmulator> emulator(std::size_t image = 1000) {
  EmulatorOptions o;
  o.expected_image_size = image;
  return std::make_shared<FalconEmulator>(o);
}

FirmwareOptions quick() {
  FirmwareOptions o;
  o.timeout_ms = 5;
  return o;
}

TEST(FalconFirmware, LoadsWithEveryEchoChecked) {
  auto emu = emulator();
  EmulatedTransport t(emu);
  int calls = 0;
  const FirmwareReport r = ensure_firmware(t, [&] { ++calls; return test::fake_image(); }, quick());
  EXPECT_TRUE(r.loaded);
  EXPECT_FALSE(r.already_running);
  EXPECT_EQ(r.attempts, 1);
  EXPECT_EQ(calls, 1);
  EXPECT_TRUE(emu->firmware_running());
  EXPECT_EQ(emu->upload_attempts(), 1);
}

TEST(FalconFirmware, SkipsLoadingWhenFirmwareRuns) {
  EmulatorOptions o;
  o.firmware_preloaded = true;
  auto emu = std::make_shared<FalconEmulator>(o);
  EmulatedTransport t(emu);
  const FirmwareReport r = ensure_firmware(t, []() -> std::vector<std::uint8_t> {
    ADD_FAILURE() << "the image must not be needed";
    return {};
  }, quick());
  EXPECT_TRUE(r.already_running);
  EXPECT_EQ(r.attempts, 0);
  EXPECT_EQ(emu->upload_attempts(), 0);
}

TEST(FalconFirmware, RetriesAfterACorruptEcho) {
  auto emu = emulator();
  emu->faults().corrupt_echo_at = 100;
  emu->faults().corrupt_attempts = 1;
  EmulatedTransport t(emu);
  const FirmwareReport r = ensure_firmware(t, [] { return test::fake_image(); }, quick());
  EXPECT_TRUE(r.loaded);
  EXPECT_EQ(r.attempts, 2);
  EXPECT_NE(r.log.find("echo mismatch at byte 100 of 1000"), std::string::npos) << r.log;
}

TEST(FalconFirmware, GivesUpAfterBoundedRetriesWithAClearReport) {
  auto emu = emulator();
  emu->faults().corrupt_echo_at = 7;
  emu->faults().corrupt_attempts = 100;
  EmulatedTransport t(emu);
  FirmwareOptions o = quick();
  o.attempts = 3;
  try {
    ensure_firmware(t, [] { return test::fake_image(); }, o);
    FAIL() << "expected a ResourceError";
  } catch (const ResourceError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("failed after 3 attempts"), std::string::npos) << m;
    EXPECT_NE(m.find("attempt 3: echo mismatch at byte 7"), std::string::npos) << m;
    EXPECT_NE(m.find("what to try"), std::string::npos) << m;
  }
  EXPECT_EQ(emu->upload_attempts(), 3);
  EXPECT_FALSE(emu->firmware_running());
}

TEST(FalconFirmware, MissingEchoIsATimeout) {
  auto emu = emulator();
  emu->faults().drop_echo_after = 499;
  emu->faults().drop_attempts = 1;
  EmulatedTransport t(emu);
  const FirmwareReport r = ensure_firmware(t, [] { return test::fake_image(); }, quick());
  EXPECT_TRUE(r.loaded);
  EXPECT_EQ(r.attempts, 2);
  EXPECT_NE(r.log.find("(timeout)"), std::string::npos) << r.log;
  EXPECT_NE(r.log.find("echo of byte 500"), std::string::npos) << r.log;
}

TEST(FalconFirmware, SilentBootLoaderIsReported) {
  auto emu = emulator();
  emu->faults().ignore_probe = true;
  EmulatedTransport t(emu);
  FirmwareOptions o = quick();
  o.attempts = 2;
  o.probe_tries = 4;
  try {
    ensure_firmware(t, [] { return test::fake_image(); }, o);
    FAIL() << "expected a ResourceError";
  } catch (const ResourceError& e) {
    EXPECT_NE(std::string(e.what()).find("did not answer the probe after 4 tries"), std::string::npos) << e.what();
  }
}

TEST(FalconFirmware, TruncatedImageNeverStartsTheFirmware) {
  auto emu = emulator(1000);
  EmulatedTransport t(emu);
  FirmwareOptions o = quick();
  o.attempts = 1;
  EXPECT_THROW(ensure_firmware(t, [] { return test::fake_image(999); }, o), ResourceError);
  EXPECT_FALSE(emu->firmware_running());
}

TEST(FalconFirmware, UnpluggedDuringUploadFails) {
  auto emu = emulator();
  EmulatedTransport t(emu);
  emu->unplug();
  FirmwareOptions o = quick();
  o.attempts = 2;
  try {
    ensure_firmware(t, [] { return test::fake_image(); }, o);
    FAIL();
  } catch (const ResourceError& e) {
    EXPECT_NE(std::string(e.what()).find("disconnected"), std::string::npos) << e.what();
  }
}

TEST(FalconFirmware, PathFromConfigThenEnvironment) {
  ::unsetenv(kFirmwareEnvVar);
  EXPECT_EQ(resolve_firmware_path("/x/fw.bin"), std::filesystem::path("/x/fw.bin"));
  try {
    resolve_firmware_path("");
    FAIL();
  } catch (const ConfigError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find(kFirmwareConfigKey), std::string::npos);
    EXPECT_NE(m.find(kFirmwareEnvVar), std::string::npos);
  }
  ::setenv(kFirmwareEnvVar, "/y/env.bin", 1);
  EXPECT_EQ(resolve_firmware_path(""), std::filesystem::path("/y/env.bin"));
  EXPECT_EQ(resolve_firmware_path("/x/fw.bin"), std::filesystem::path("/x/fw.bin"));  // config wins
  ::unsetenv(kFirmwareEnvVar);
}

TEST(FalconFirmware, ImageFileErrorsNameTheFile) {
  const auto dir = hc::test::temp_dir("falcon_fw_errors");
  EXPECT_THROW(read_firmware_image(dir / "missing.bin"), InputError);
  const auto empty = dir / "empty.bin";
  std::ofstream(empty).close();
  try {
    read_firmware_image(empty);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("empty.bin"), std::string::npos);
  }
  const auto ok = test::write_fake_image("falcon_fw_ok", 321);
  EXPECT_EQ(read_firmware_image(ok), test::fake_image(321));
}

}  // namespace
}  // namespace hc::falcon
