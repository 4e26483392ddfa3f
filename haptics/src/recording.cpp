#include "hc/haptics/recording.hpp"

#include "hc/common/error.hpp"
#include "hc/common/file_output.hpp"

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <system_error>
#include <utility>

#include <fcntl.h>
#include <unistd.h>

namespace hc::haptics {

namespace {

constexpr const char* kMagic = "# hapticloud recording 2";
constexpr const char* kMagicV1 = "# hapticloud recording 1";
constexpr const char* kColumns = "tick,time_ns,x_m,y_m,z_m,buttons,fx_n,fy_n,fz_n,status";

// One sample as a line of text, doubles as %.17g (they read back bit for bit).
int format_sample(const RecordedSample& s, char* buf, std::size_t size) {
  return std::snprintf(buf, size, "%llu,%lld,%.17g,%.17g,%.17g,%u,%.17g,%.17g,%.17g,%u\n",
                       static_cast<unsigned long long>(s.tick), static_cast<long long>(s.time_ns), s.position_m[0],
                       s.position_m[1], s.position_m[2], s.buttons, s.force_n[0], s.force_n[1], s.force_n[2],
                       static_cast<unsigned>(s.status));
}

}  // namespace

RecordingDevice::RecordingDevice(HapticDevice& inner, std::filesystem::path file)
    : HapticDevice(inner.info()), inner_(inner), file_(std::move(file)) {}

RecordingDevice::~RecordingDevice() { close(); }

void RecordingDevice::watch(SharedState& shared, double servo_rate_hz) {
  if (!(servo_rate_hz > 0.0) || !std::isfinite(servo_rate_hz)) {
    throw ConfigError("record: servo rate " + std::to_string(servo_rate_hz) + " Hz (expected > 0)");
  }
  if (writer_.joinable()) throw ConfigError("record: watch() after open(); call it before the recording starts");
  shared.enable_servo_log();
  shared_ = &shared;
  servo_rate_hz_ = servo_rate_hz;
}

void RecordingDevice::note(const std::string& action) {
  if (shared_ == nullptr || !writer_.joinable()) return;
  std::string one_line = action;
  for (char& c : one_line) if (c == '\n' || c == '\r') c = ' ';
  const std::lock_guard<std::mutex> lock(notes_mutex_);
  notes_.emplace_back(shared_->counters.ticks.load(std::memory_order_relaxed), std::move(one_line));
}

void RecordingDevice::do_open() {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::exists(fs::symlink_status(file_, ec))) {
    throw InputError("record: " + file_.string() + " exists already (not overwritten; choose another --record)");
  }
  const fs::path folder = file_.has_parent_path() ? file_.parent_path() : fs::path(".");
  if (!fs::is_directory(folder, ec)) throw InputError("record: folder " + folder.string() + " of " + file_.string() + " does not exist");
  inner_.open();
  // The temporary (exclusive), linked to FILE by close() after keep_on_close().
  try {
    tmp_ = create_temporary_beside(file_);
  } catch (const InputError& e) {
    inner_.close();
    throw InputError(std::string("record: ") + e.what());
  }
  try {
    ring_ = std::make_unique<SpscRing<RecordedSample, 16384>>();
    stop_.store(false);
    written_.store(0);
    dropped_.store(0);
    has_pending_ = false;
    next_tick_ = 0;
    error_.clear();
    keep_ = false;
    write_failed_ = false;
    log_dropped_at_open_ = shared_ != nullptr ? shared_->servo_log_dropped() : 0;
    writer_ = std::thread([this] { writer_loop(); });
  } catch (...) {
    std::filesystem::remove(tmp_, ec);
    tmp_.clear();
    inner_.close();
    throw;
  }
}

void RecordingDevice::writer_loop() {
  std::ofstream out(tmp_, std::ios::binary | std::ios::trunc);
  if (!out) {
    write_failed_ = true;
    return;
  }
  out.precision(17);
  out << kMagic << "\n# device: " << info().name << "; nominal_rate_hz: " << info().nominal_rate_hz
      << "; max_force_n: " << info().max_force_n;
  if (servo_rate_hz_ > 0.0) out << "; servo_rate_hz: " << servo_rate_hz_;
  out << "\n" << kColumns << "\n";
  char buf[512];
  RecordedSample s;
  ServoLogEntry e;
  std::vector<std::pair<std::uint64_t, std::string>> notes;
  for (;;) {
    const bool last = stop_.load(std::memory_order_acquire);
    while (ring_->try_pop(s)) {
      const int n = format_sample(s, buf, sizeof buf);
      out.write(buf, n);
      written_.fetch_add(1, std::memory_order_relaxed);
    }
    if (shared_ != nullptr && shared_->servo_log() != nullptr) {
      while (shared_->servo_log()->try_pop(e)) {
        int n = 0;
        if (e.kind == ServoLogEntry::Kind::kSurface) {
          n = std::snprintf(buf, sizeof buf, "@surface,%llu,%llu\n", static_cast<unsigned long long>(e.tick),
                            static_cast<unsigned long long>(e.surface_tag));
        } else {
          const Command& c = e.command;
          n = std::snprintf(buf, sizeof buf, "@%s,%llu,%s,%.17g,%.17g,%.17g,%.17g,%.17g\n",
                            e.kind == ServoLogEntry::Kind::kCommand ? "command" : "rejected",
                            static_cast<unsigned long long>(e.tick), to_string(c.type), c.a, c.b, c.c, c.d, c.e);
        }
        out.write(buf, n);
      }
    }
    {
      const std::lock_guard<std::mutex> lock(notes_mutex_);
      notes.swap(notes_);
    }
    for (const auto& [tick, action] : notes) out << "@session," << tick << "," << action << "\n";
    notes.clear();
    if (last) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  out.flush();
  if (!out) write_failed_ = true;
}

void RecordingDevice::push(const RecordedSample& s) noexcept {
  if (!ring_->try_push(s)) dropped_.fetch_add(1, std::memory_order_relaxed);
}

DeviceStatus RecordingDevice::do_read(DeviceReading& out) noexcept {
  DeviceStatus st = inner_.read(out);
  // A fault of the inner device (its own watchdog, say) must reach the servo loop; one this
  // device put there (mirrored, awaiting the reset) must not.
  if (inner_.state() == DeviceState::kFault && state() != DeviceState::kFault && !inner_faulted_by_mirror_) {
    st = DeviceStatus::kIoError;
  }
  if (has_pending_) push(pending_);  // a read without a write: its force is NaN
  pending_.tick = next_tick_++;
  pending_.time_ns = out.time_ns;
  for (int a = 0; a < 3; ++a) {
    pending_.position_m[a] = out.position_m[a];
    pending_.force_n[a] = std::numeric_limits<double>::quiet_NaN();
  }
  pending_.buttons = out.buttons;
  pending_.status = static_cast<std::uint8_t>(st);
  has_pending_ = true;
  return st;
}

DeviceStatus RecordingDevice::do_write(const Eigen::Vector3d& force_n) noexcept {
  // Mirror this device's state onto the inner one, so that it renders what is sent here.
  // (this Fault → inner Fault; an explicit reset of this device, seen as Open here while the
  // inner one is in Fault, resets it; Armed/Open follow).
  const DeviceState mine = state();
  if (mine == DeviceState::kFault && inner_.state() != DeviceState::kFault) inner_.fault();
  if (mine == DeviceState::kOpen && inner_.state() == DeviceState::kFault && inner_faulted_by_mirror_) inner_.reset_fault();
  if (mine == DeviceState::kArmed && inner_.state() == DeviceState::kOpen) inner_.arm();
  if (mine != DeviceState::kArmed && inner_.state() == DeviceState::kArmed) inner_.disarm();
  inner_faulted_by_mirror_ = inner_.state() == DeviceState::kFault && (mine == DeviceState::kFault || inner_faulted_by_mirror_);
  DeviceStatus st = inner_.write(force_n);
  if (st == DeviceStatus::kFault && mine != DeviceState::kFault && !inner_faulted_by_mirror_) st = DeviceStatus::kIoError;
  if (has_pending_) {
    const Eigen::Vector3d& sent = inner_.last_force_n();
    for (int a = 0; a < 3; ++a) pending_.force_n[a] = sent[a];
    push(pending_);
    has_pending_ = false;
  }
  return st;
}

void RecordingDevice::do_close() noexcept {
  if (has_pending_) {
    push(pending_);
    has_pending_ = false;
  }
  if (writer_.joinable()) {
    stop_.store(true, std::memory_order_release);
    writer_.join();
  }
  inner_.close();
  if (tmp_.empty()) return;
  std::error_code ec;
  bool remove_tmp = true;
  if (!keep_) {
    error_ = "record: the session did not end normally; no recording kept";
  } else if (write_failed_) {
    error_ = "record: writing " + tmp_.string() + " failed (disk full?); no recording kept";
  } else if (dropped_.load() > 0) {
    error_ = "record: " + std::to_string(dropped_.load()) + " ticks were lost (the writer fell behind); no recording kept";
  } else if (shared_ != nullptr && shared_->servo_log_dropped() > log_dropped_at_open_) {
    error_ = "record: " + std::to_string(shared_->servo_log_dropped() - log_dropped_at_open_) +
             " servo events (commands, surface switches) were lost (the writer fell behind); no recording kept";
  } else if (!link_into_place(tmp_, file_)) {
    if (errno == EEXIST) {
      error_ = "record: cannot put " + file_.string() + " in place: it exists already (not overwritten)";
    } else {
      // No hard links here (FAT, some network shares): the recording stays under its .part name.
      error_ = "record: cannot link " + file_.string() + " (" + std::strerror(errno) + "); the recording is kept as " +
               tmp_.string();
      remove_tmp = false;
    }
  }
  if (remove_tmp) std::filesystem::remove(tmp_, ec);
  tmp_.clear();
}

namespace {

[[noreturn]] void bad_line(const std::filesystem::path& file, int line_no, const std::string& line, const std::string& expected) {
  throw InputError("replay: " + file.string() + ":" + std::to_string(line_no) + ": '" + line + "' is not " + expected);
}

// "@kind,tick,..." → an event.
RecordedEvent parse_event(const std::filesystem::path& file, int line_no, const std::string& line) {
  RecordedEvent ev;
  const std::size_t c1 = line.find(',');
  const std::size_t c2 = c1 == std::string::npos ? std::string::npos : line.find(',', c1 + 1);
  if (c2 == std::string::npos) bad_line(file, line_no, line, "an event: @command|@rejected|@surface|@session,TICK,...");
  const std::string kind = line.substr(1, c1 - 1), tick = line.substr(c1 + 1, c2 - c1 - 1), rest = line.substr(c2 + 1);
  char* end = nullptr;
  ev.tick = std::strtoull(tick.c_str(), &end, 10);
  if (tick.empty() || *end != '\0' || tick[0] == '-') bad_line(file, line_no, line, "an event with a tick (an integer >= 0)");
  if (kind == "session") {
    ev.kind = RecordedEvent::Kind::kSession;
    ev.action = rest;
  } else if (kind == "surface") {
    ev.kind = RecordedEvent::Kind::kSurface;
    ev.surface_tag = std::strtoull(rest.c_str(), &end, 10);
    if (rest.empty() || *end != '\0' || rest[0] == '-') bad_line(file, line_no, line, "@surface,TICK,TAG (integers)");
  } else if (kind == "command" || kind == "rejected") {
    ev.kind = kind == "command" ? RecordedEvent::Kind::kCommand : RecordedEvent::Kind::kRejected;
    const std::size_t c3 = rest.find(',');
    if (c3 == std::string::npos || !command_type_from_string(rest.substr(0, c3), ev.command.type)) {
      bad_line(file, line_no, line, "@" + kind + ",TICK,NAME,a,b,c,d,e with a known command name");
    }
    Command& c = ev.command;
    int used = 0;
    const std::string nums = rest.substr(c3 + 1);
    if (std::sscanf(nums.c_str(), "%lf,%lf,%lf,%lf,%lf%n", &c.a, &c.b, &c.c, &c.d, &c.e, &used) != 5 ||
        static_cast<std::size_t>(used) != nums.size()) {
      bad_line(file, line_no, line, "@" + kind + ",TICK,NAME,a,b,c,d,e (five numbers)");
    }
  } else {
    bad_line(file, line_no, line, "an event: @command|@rejected|@surface|@session,TICK,...");
  }
  return ev;
}

double header_number(const std::string& line, const std::string& key) {
  const std::size_t at = line.find(key + ": ");
  if (at == std::string::npos) return 0.0;
  const double v = std::strtod(line.c_str() + at + key.size() + 2, nullptr);
  return v > 0.0 && std::isfinite(v) ? v : 0.0;
}

}  // namespace

Recording read_recording_file(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) throw InputError("replay: cannot open " + file.string());
  std::string line;
  Recording rec;
  if (!std::getline(in, line)) line.clear();
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line == kMagic) {
    rec.version = 2;
  } else if (line == kMagicV1) {
    rec.version = 1;
  } else {
    throw InputError("replay: " + file.string() + ":1: expected '" + std::string(kMagic) +
                     "' (or version 1; a file written by --record)");
  }
  std::vector<RecordedSample>& out = rec.samples;
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.rfind("# device:", 0) == 0) {
      rec.servo_rate_hz = header_number(line, "servo_rate_hz");
      rec.max_force_n = header_number(line, "max_force_n");
      continue;
    }
    if (line.empty() || line[0] == '#' || line == kColumns) continue;
    if (line[0] == '@') {
      rec.events.push_back(parse_event(file, line_no, line));
      continue;
    }
    RecordedSample s;
    unsigned long long tick = 0;
    long long time_ns = 0;
    unsigned buttons = 0, status = 0;
    int used = 0;
    const int n = std::sscanf(line.c_str(), "%llu,%lld,%lf,%lf,%lf,%u,%lf,%lf,%lf,%u%n", &tick, &time_ns, &s.position_m[0],
                              &s.position_m[1], &s.position_m[2], &buttons, &s.force_n[0], &s.force_n[1], &s.force_n[2],
                              &status, &used);
    if (n != 10 || static_cast<std::size_t>(used) != line.size() || !std::isfinite(s.position_m[0]) ||
        !std::isfinite(s.position_m[1]) || !std::isfinite(s.position_m[2]) || status > 5) {
      bad_line(file, line_no, line, std::string(kColumns) + " (ten numbers, a finite position, a status 0..5)");
    }
    s.status = static_cast<std::uint8_t>(status);
    if (tick != out.size()) {
      throw InputError("replay: " + file.string() + ":" + std::to_string(line_no) + ": tick " + std::to_string(tick) +
                       ", expected " + std::to_string(out.size()) + " (ticks count up from 0 by one)");
    }
    s.tick = tick;
    s.time_ns = time_ns;
    s.buttons = buttons;
    out.push_back(s);
  }
  if (out.empty()) throw InputError("replay: " + file.string() + " holds no samples");
  return rec;
}

std::vector<RecordedSample> read_recording(const std::filesystem::path& file) {
  return read_recording_file(file).samples;
}

namespace {

// `info` with max_force_n from the recording's "# device: ...; max_force_n: X" line, if any.
DeviceInfo info_from(const std::filesystem::path& file, DeviceInfo info) {
  std::ifstream in(file);
  std::string line;
  for (int k = 0; k < 2 && std::getline(in, line); ++k) {
    const std::size_t at = line.find("max_force_n: ");
    if (at == std::string::npos) continue;
    const double v = std::strtod(line.c_str() + at + 13, nullptr);
    if (v > 0.0 && std::isfinite(v)) info.max_force_n = v;
  }
  return info;
}

}  // namespace

TickReplayDevice::TickReplayDevice(const Clock& clock, std::filesystem::path file, DeviceInfo info)
    : HapticDevice(info_from(file, std::move(info))), clock_(clock), file_(std::move(file)) {}

namespace {
DeviceInfo with_cap(DeviceInfo info, const Recording& r) {
  if (r.max_force_n > 0.0) info.max_force_n = r.max_force_n;
  return info;
}
}  // namespace

TickReplayDevice::TickReplayDevice(const Clock& clock, Recording recording, DeviceInfo info)
    : HapticDevice(with_cap(std::move(info), recording)), clock_(clock), given_(true) {
  if (recording.samples.empty()) throw InputError("replay: the recording holds no samples");
  samples_ = std::move(recording.samples);
  recording.samples.clear();
  recording_ = std::move(recording);
}

void TickReplayDevice::do_open() {
  if (given_) {
    next_ = 0;
    return;
  }
  recording_ = read_recording_file(file_);
  samples_ = std::move(recording_.samples);
  recording_.samples.clear();
  next_ = 0;
}

DeviceStatus TickReplayDevice::do_read(DeviceReading& out) noexcept {
  if (next_ == 0) start_ns_ = clock_.now_ns();
  const bool done = next_ >= samples_.size();
  const RecordedSample& s = samples_[done ? samples_.size() - 1 : next_];
  out.position_m = Eigen::Vector3d(s.position_m[0], s.position_m[1], s.position_m[2]);
  out.buttons = s.buttons;
  out.time_ns = start_ns_ + (s.time_ns - samples_.front().time_ns);
  if (done) return DeviceStatus::kEndOfData;
  ++next_;
  return static_cast<DeviceStatus>(s.status);
}

}  // namespace hc::haptics
