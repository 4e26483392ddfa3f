// Stage 1: reading scans. This file holds what every format shares: reading the file once,
// gzip decompression (zlib, in memory), the dispatch by extension to one reader per format
// (pipeline/src/readers/, interface in readers/readers.hpp) and the multi-view merge.
// A new format is a new readers/read_<format>.cpp plus one line in kFormats below.

#include "readers/readers.hpp"
#include "readers/text_parse.hpp"
#include "stage_util.hpp"
#include "hc/pipeline/ingest.hpp"

#include "hc/common/error.hpp"

#include <libdeflate.h>
#include <memory>
#include <zlib.h>

#include <algorithm>
#include <atomic>
#include <exception>
#include <fstream>
#include <limits>
#include <string_view>
#include <system_error>
#include <thread>
#include <type_traits>

namespace hc::pipeline {

namespace {

using detail::Clock;
using detail::lower;
using detail::quoted;
using detail::seconds_since;

/// The readers, by extension (lower case, after any .gz is stripped).
struct Format {
  std::string_view extension;
  detail::ReaderFn read;
};
constexpr Format kFormats[] = {
    {".ply", detail::read_ply},
    {".pcd", detail::read_pcd},
    {".obj", detail::read_obj},
    {".xyz", detail::read_xyz},
    {".txt", detail::read_xyz},
    {".e57", detail::read_e57},
    {".las", detail::read_las},
    {".laz", detail::read_laz},
    {".ptx", detail::read_ptx},
    {".pts", detail::read_pts},
};

// ".ply, .pcd, .obj, .xyz or .txt"
std::string known_extensions() {
  std::string s;
  const std::size_t n = std::size(kFormats);
  for (std::size_t i = 0; i < n; ++i) {
    if (i > 0) s += i + 1 == n ? " or " : ", ";
    s += kFormats[i].extension;
  }
  return s;
}

// ---------------------------------------------------------------------------------------------
// Whole-file reading and gzip.

std::string read_whole_file(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    throw InputError("load_cloud: file " + quoted(path) + " does not exist");
  }
  if (std::filesystem::is_directory(path, ec)) {
    throw InputError("load_cloud: " + quoted(path) + " is a directory, expected a scan file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("load_cloud: cannot open " + quoted(path) + " for reading");
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  if (size < 0) throw InputError("load_cloud: cannot determine the size of " + quoted(path));
  in.seekg(0, std::ios::beg);
  std::string bytes(static_cast<std::size_t>(size), '\0');
  if (size > 0 && !in.read(bytes.data(), size)) {
    throw InputError("load_cloud: read error on " + quoted(path));
  }
  if (bytes.empty()) throw detail::empty_file_error(quoted(path));
  return bytes;
}

// gzip through libdeflate (Debian's libdeflate0: whole-buffer inflate, about twice zlib's
// speed): every member of a gzip file in turn, the output sized from the last member's ISIZE
// and doubled when short. Returns false (and nothing) on data it does not accept, so that zlib's
// streaming inflate below decides and words the error.
bool gunzip_libdeflate(const std::string& packed, std::size_t guess, std::string& out) {
  if (packed.size() < 18 || static_cast<unsigned char>(packed[0]) != 0x1f || static_cast<unsigned char>(packed[1]) != 0x8b) {
    return false;
  }
  std::unique_ptr<libdeflate_decompressor, void (*)(libdeflate_decompressor*)> d(libdeflate_alloc_decompressor(),
                                                                                  &libdeflate_free_decompressor);
  if (!d) return false;
  out.resize(std::max<std::size_t>(guess, 1 << 16));
  std::size_t consumed = 0, produced = 0;
  while (consumed < packed.size()) {
    std::size_t in_used = 0, out_used = 0;
    const libdeflate_result r =
        libdeflate_gzip_decompress_ex(d.get(), packed.data() + consumed, packed.size() - consumed, out.data() + produced,
                                      out.size() - produced, &in_used, &out_used);
    if (r == LIBDEFLATE_INSUFFICIENT_SPACE) {
      if (out.size() > (std::size_t{1} << 40)) return false;
      out.resize(out.size() * 2);
      continue;
    }
    if (r != LIBDEFLATE_SUCCESS) return false;
    consumed += in_used;
    produced += out_used;
  }
  out.resize(produced);
  out.shrink_to_fit();
  return true;
}

// Inflates a gzip (or zlib) stream held in memory; concatenated gzip members are all inflated.
std::string gunzip(const std::string& packed, const std::filesystem::path& path) {
  {
    std::size_t guess = packed.size() * 2;
    if (packed.size() >= 18) {
      std::uint32_t isize = 0;
      for (std::size_t i = 1; i <= 4; ++i) isize = (isize << 8) | static_cast<unsigned char>(packed[packed.size() - i]);
      if (isize >= packed.size() / 2 && isize / 16 <= packed.size()) guess = static_cast<std::size_t>(isize);
    }
    std::string out;
    if (gunzip_libdeflate(packed, guess, out)) {
      if (out.empty()) throw detail::gzip_empty_error(quoted(path));
      return out;
    }
  }
  z_stream zs{};
  // 15 + 32: maximum window, detect gzip or zlib header automatically.
  if (inflateInit2(&zs, 15 + 32) != Z_OK) {
    throw ResourceError("load_cloud: zlib could not initialise an inflate stream for " + quoted(path));
  }
  std::string out;
  // A gzip member ends with its uncompressed size mod 2^32 (ISIZE): size the output from it
  // when it is plausible, else guess twice the input; grow geometrically if needed.
  std::size_t guess = packed.size() * 2;
  if (packed.size() >= 18 && static_cast<unsigned char>(packed[0]) == 0x1f &&
      static_cast<unsigned char>(packed[1]) == 0x8b) {
    std::uint32_t isize = 0;
    for (std::size_t i = 1; i <= 4; ++i) isize = (isize << 8) | static_cast<unsigned char>(packed[packed.size() - i]);
    // Trusted only up to 16x the input (a corrupt trailer must not allocate gigabytes).
    if (isize >= packed.size() / 2 && isize / 16 <= packed.size()) guess = static_cast<std::size_t>(isize) + 1;
  }
  out.resize(std::max<std::size_t>(guess, 1 << 16));
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(packed.data()));
  std::size_t in_left = packed.size();
  std::size_t produced = 0;
  int rc = Z_OK;
  for (;;) {
    if (produced == out.size()) out.resize(out.size() * 2);
    const std::size_t in_chunk = std::min<std::size_t>(in_left, std::numeric_limits<uInt>::max());
    const std::size_t out_chunk = std::min<std::size_t>(out.size() - produced, std::numeric_limits<uInt>::max());
    zs.avail_in = static_cast<uInt>(in_chunk);
    zs.next_out = reinterpret_cast<Bytef*>(out.data() + produced);
    zs.avail_out = static_cast<uInt>(out_chunk);
    rc = inflate(&zs, Z_NO_FLUSH);
    in_left -= in_chunk - zs.avail_in;
    produced += out_chunk - zs.avail_out;
    if (rc == Z_STREAM_END) {
      if (in_left == 0) break;
      // Another gzip member follows (as `cat a.gz b.gz` produces).
      if (inflateReset(&zs) != Z_OK) break;
      continue;
    }
    if (rc == Z_BUF_ERROR && in_left == 0 && zs.avail_out != 0) break;  // input ended early
    if (rc != Z_OK && rc != Z_BUF_ERROR) break;
  }
  const std::string msg = zs.msg ? zs.msg : "";
  inflateEnd(&zs);
  if (rc != Z_STREAM_END) {
    throw detail::gzip_data_error(quoted(path), rc == Z_BUF_ERROR || rc == Z_OK, msg.empty() ? nullptr : msg.c_str(), packed.size());
  }
  out.resize(produced);
  if (out.empty()) throw detail::gzip_empty_error(quoted(path));
  return out;
}

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::string strip_gz(const std::string& file_name) {
  return ends_with(lower(file_name), ".gz") ? file_name.substr(0, file_name.size() - 3) : file_name;
}

}  // namespace

StageResult<Cloud> load_cloud(const std::filesystem::path& path) { return load_cloud(path, LoadOptions{}); }

StageResult<Cloud> load_cloud(const std::filesystem::path& path, const LoadOptions& options) {
  const auto t0 = Clock::now();
  StageReport report;
  report.stage = "load";
  const std::string name = quoted(path);

  std::string file_name = lower(path.filename().string());
  const bool gz = ends_with(file_name, ".gz");
  if (gz) file_name.resize(file_name.size() - 3);
  const std::string ext = std::filesystem::path(file_name).extension().string();
  const auto format = std::find_if(std::begin(kFormats), std::end(kFormats),
                                   [&](const Format& f) { return f.extension == ext; });
  if (format == std::end(kFormats)) {
    throw InputError("load_cloud: " + name + " has an unknown extension '" + ext + "' (expected " +
                     known_extensions() + ", optionally followed by .gz)");
  }

  std::string bytes = read_whole_file(path);
  report.figure("file_bytes", static_cast<double>(bytes.size()));
  if (gz) {
    const auto tz = Clock::now();
    bytes = gunzip(bytes, path);
    report.figure("decompressed_bytes", static_cast<double>(bytes.size()));
    report.figure("decompress_s", seconds_since(tz));
  }

  const auto tp = Clock::now();
  detail::ReadResult read = format->read(detail::ScanSource{bytes, path, gz, name, &options});
  Cloud& cloud = read.cloud;
  report.notes.insert(report.notes.end(), read.notes.begin(), read.notes.end());
  report.figure("parse_s", seconds_since(tp));
  if (cloud.size() == 0) throw InputError("load_cloud: " + name + " holds no points");
  if (options.as_points && cloud.has_mesh()) {
    report.notes.push_back("input.as_points: dropped the " + std::to_string(cloud.mesh.triangles.size()) +
                           " triangles of the file's faces; its vertices are used as points");
    cloud.mesh = Mesh{};
  }
  if (cloud.has_mesh()) report.figure("triangles", static_cast<double>(cloud.mesh.triangles.size()));
  report.count_in = cloud.size();
  report.count_out = cloud.size();
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

namespace {
// Whether every part (of files[i]) has the attribute `has` tells; when not, and another part
// has it, a note "<key>: <what> dropped: <the first file without it> has none".
template <class Has>
bool every_part_has(const std::vector<Cloud>& parts, const std::vector<std::filesystem::path>& files, const char* key, const char* what,
                    Has&& has, StageReport& report) {
  for (std::size_t i = 0; i < parts.size(); ++i) {
    if (has(parts[i])) continue;
    if (std::any_of(parts.begin(), parts.end(), has)) {
      report.notes.push_back(std::string(key) + ": " + what + " dropped: " + files[i].filename().string() + " has none");
    }
    return false;
  }
  return true;
}
}  // namespace

std::vector<Eigen::Affine3d> scan_poses(const std::vector<std::filesystem::path>& scans, const std::filesystem::path& conf_path) {
  if (scans.empty()) throw InputError("input.conf: no scan files given (conf " + quoted(conf_path) + ")");
  if (scans.size() > std::numeric_limits<std::uint16_t>::max()) {
    throw InputError("input.conf: " + std::to_string(scans.size()) + " scans given, at most 65535 supported");
  }
  const std::vector<ScanPose> poses = read_scanalyze_conf(conf_path);
  std::vector<Eigen::Affine3d> out;
  out.reserve(scans.size());
  for (const auto& scan : scans) {
    const std::string want = strip_gz(scan.filename().string());
    const ScanPose* found = nullptr;
    for (const auto& pose : poses) {
      if (strip_gz(std::filesystem::path(pose.file).filename().string()) == want) {
        found = &pose;
        break;
      }
    }
    if (!found) {
      throw InputError("input.conf: scan " + quoted(scan) + " has no bmesh line named '" + want + "' in " + quoted(conf_path));
    }
    out.push_back(found->scan_to_world());
  }
  return out;
}

// Not inlined: one body for both callers, so a build that contracts to FMAs contracts both alike.
[[gnu::noinline]] void move_to_world(const Eigen::Affine3d& scan_to_world, Eigen::Matrix3Xd& xyz) {
  const Eigen::Matrix3d l = scan_to_world.linear();
  const Eigen::Vector3d t = scan_to_world.translation();
  double* p = xyz.data();
  const Eigen::Index n = xyz.cols();
  for (Eigen::Index i = 0; i < n; ++i, p += 3) {
    const double x = p[0], y = p[1], z = p[2];
    for (int a = 0; a < 3; ++a) p[a] = ((l(a, 0) * x + l(a, 1) * y) + l(a, 2) * z) + t[a];
  }
}

StageResult<Cloud> load_and_merge_scans(const std::vector<std::filesystem::path>& scans,
                                        const std::filesystem::path& conf_path, const LoadOptions& options) {
  const auto t0 = Clock::now();
  const std::vector<Eigen::Affine3d> matched = scan_poses(scans, conf_path);  // every pose before any scan is read
  StageReport report;
  report.stage = "load";

  // Scans are read and moved into the common frame on two threads; the first error (in scan
  // order) is rethrown.
  std::vector<Cloud> parts(scans.size());
  std::vector<std::exception_ptr> errors(scans.size());
  std::vector<std::vector<std::string>> part_notes(scans.size());
  std::atomic<std::size_t> next{0};
  auto worker = [&] {
    for (std::size_t i; (i = next.fetch_add(1)) < scans.size();) {
      try {
        StageResult<Cloud> loaded = load_cloud(scans[i], options);
        Cloud c = std::move(loaded.value);
        for (const auto& note : loaded.report.notes) {  // faces, range grid, drops: never silent
          if (note.find("dropped") != std::string::npos || note.find("not used") != std::string::npos ||
              note.find("as_points") != std::string::npos) {
            part_notes[i].push_back(scans[i].filename().string() + ": " + note);
          }
        }
        move_to_world(matched[i], c.xyz);
        parts[i] = std::move(c);
      } catch (...) {
        errors[i] = std::current_exception();
      }
    }
  };
  {
    std::thread helper;
    if (scans.size() > 1) helper = std::thread(worker);
    worker();
    if (helper.joinable()) helper.join();
  }
  for (const auto& e : errors) {
    if (e) std::rethrow_exception(e);
  }
  std::size_t total = 0;
  for (std::size_t i = 0; i < scans.size(); ++i) {
    total += parts[i].size();
    report.notes.push_back(scans[i].filename().string() + ": " + std::to_string(parts[i].size()) + " points");
    report.notes.insert(report.notes.end(), part_notes[i].begin(), part_notes[i].end());
  }

  // Scanner row/col (organised scans), colour and intensity are kept when every scan has them
  // (a note names the first scan without colour or intensity when another has it), and faces
  // (meshes) are renumbered into the merged points; other per-point attributes are not merged.
  const bool grid_index =
      std::all_of(parts.begin(), parts.end(), [](const Cloud& c) { return c.has_grid_index(); });
  const auto every = [&](const char* what, auto&& has) { return every_part_has(parts, scans, "input.conf", what, has, report); };
  const bool rgb = every("rgb", [](const Cloud& c) { return c.has_rgb(); });
  const bool intensity = every("intensity", [](const Cloud& c) { return c.has_intensity(); });
  Cloud merged;
  merged.xyz.resize(3, static_cast<Eigen::Index>(total));
  merged.scan_id.resize(total);
  if (grid_index) {
    merged.row.reserve(total);
    merged.col.reserve(total);
  }
  Eigen::Index at = 0;
  std::size_t dropped_textures = 0;
  for (std::size_t i = 0; i < parts.size(); ++i) {
    const Eigen::Index n = parts[i].xyz.cols();
    merged.xyz.middleCols(at, n) = parts[i].xyz;
    std::fill_n(merged.scan_id.begin() + at, n, static_cast<std::uint16_t>(i));
    if (grid_index) {
      merged.row.insert(merged.row.end(), parts[i].row.begin(), parts[i].row.end());
      merged.col.insert(merged.col.end(), parts[i].col.begin(), parts[i].col.end());
    }
    if (rgb) merged.rgb.insert(merged.rgb.end(), parts[i].rgb.begin(), parts[i].rgb.end());
    if (intensity) merged.intensity.insert(merged.intensity.end(), parts[i].intensity.begin(), parts[i].intensity.end());
    dropped_textures += parts[i].mesh.has_texture() ? 1 : 0;
    if (total > 0xFFFFFFFEu && parts[i].has_mesh()) {
      report.notes.push_back(scans[i].filename().string() + ": dropped its " +
                             std::to_string(parts[i].mesh.triangles.size()) +
                             " triangles: the merged scans have more points than 32-bit indices reach");
      parts[i].mesh = Mesh{};
    }
    for (auto tri : parts[i].mesh.triangles) {
      for (auto& v : tri) v += static_cast<std::uint32_t>(at);
      merged.mesh.triangles.push_back(tri);
    }
    at += n;
  }
  if (merged.has_mesh()) {
    report.notes.push_back("faces of the scans merged: " + std::to_string(merged.mesh.triangles.size()) + " triangles");
  }
  if (dropped_textures > 0) {
    report.notes.push_back("textures of " + std::to_string(dropped_textures) + " scans not used (merged meshes carry no texture)");
  }

  report.figure("scans", static_cast<double>(scans.size()));
  report.count_in = total;
  report.count_out = total;
  report.seconds = seconds_since(t0);
  return {std::move(merged), std::move(report)};
}

void check_same_crs(std::pair<std::string, std::string>& crs, const std::string& file_crs, const std::filesystem::path& file) {
  if (file_crs.empty()) return;
  if (crs.first.empty()) {
    crs = {file_crs, file.string()};
    return;
  }
  if (file_crs != crs.first) {
    throw InputError("input.shared_frame: " + quoted(file) + " declares the coordinate reference system '" + file_crs + "' but " +
                     quoted(std::filesystem::path(crs.second)) + " declares '" + crs.first +
                     "': expected files in one frame (reproject them to one CRS first)");
  }
}

StageResult<Cloud> load_files_in_one_frame(const std::vector<std::filesystem::path>& files, const LoadOptions& options) {
  const auto t0 = Clock::now();
  if (files.empty()) throw InputError("load_files_in_one_frame: no files given (input.files is empty)");
  StageReport report;
  report.stage = "load";
  std::vector<Cloud> parts;
  parts.reserve(files.size());
  std::pair<std::string, std::string> crs;  // the CRS seen first and its file
  for (const auto& f : files) {
    StageResult<Cloud> part = load_cloud(f, options);
    check_same_crs(crs, part.value.crs, f);
    const std::string name = f.filename().string();
    report.notes.push_back(name + ": " + std::to_string(part.value.size()) + " points");
    for (const auto& note : part.report.notes) report.notes.push_back(name + ": " + note);
    parts.push_back(std::move(part.value));
  }
  // An attribute is kept when every part has it; else a note names the first part without it
  // (the stream's wording, open_point_streams).
  const auto every = [&](const char* what, auto&& has) { return every_part_has(parts, files, "input.shared_frame", what, has, report); };
  const bool rgb = every("rgb", [](const Cloud& c) { return c.has_rgb(); });
  const bool intensity = every("intensity", [](const Cloud& c) { return c.has_intensity(); });
  const bool normals = every("normal", [](const Cloud& c) { return c.has_normals(); });
  const bool curvature = normals && every("curvature", [](const Cloud& c) { return !c.curvature.empty(); });
  bool grid_index = every("scanner row/column", [](const Cloud& c) { return c.has_grid_index(); });
  // Scan ids made distinct across the files (a file's own ids, or 0, plus the scans of the files
  // before it): scanner rows and columns are per scan (mesh_organised_scans).
  std::vector<std::size_t> scans_of(parts.size(), 1);  // per part, its scans
  std::size_t scans = 0, total = 0;
  for (std::size_t i = 0; i < parts.size(); ++i) {
    for (const auto s : parts[i].scan_id) scans_of[i] = std::max<std::size_t>(scans_of[i], std::size_t{s} + 1);
    scans += scans_of[i];
    total += parts[i].size();
  }
  if (total > 0xFFFFFFFEu && std::any_of(parts.begin(), parts.end(), [](const Cloud& c) { return c.has_mesh(); })) {
    throw InputError("input.shared_frame: the files hold " + std::to_string(total) +
                     " points with faces: more than 32-bit face indices reach (input.as_points: true takes the vertices)");
  }
  const bool scan_id = scans <= std::numeric_limits<std::uint16_t>::max() + std::size_t{1};
  if (!scan_id) {
    report.notes.push_back("input.shared_frame: scan ids and scanner row/column dropped: the files hold " + std::to_string(scans) +
                           " scans, more than 65536");
    grid_index = false;
  }
  // The texture when every mesh has one and they share its image (Cloud::append's rule).
  const auto first_mesh = std::find_if(parts.begin(), parts.end(), [](const Cloud& c) { return !c.mesh.empty(); });
  bool texture = first_mesh != parts.end();
  for (const Cloud& c : parts) {
    texture = texture && (c.mesh.empty() || (c.mesh.has_texture() && c.mesh.texture == first_mesh->mesh.texture));
  }
  if (!texture && std::any_of(parts.begin(), parts.end(), [](const Cloud& c) { return c.mesh.has_texture(); })) {
    report.notes.push_back("input.shared_frame: texture dropped: the meshes do not share one texture image");
  }
  Cloud all;
  all.xyz.resize(3, static_cast<Eigen::Index>(total));
  Eigen::Index at = 0;
  std::size_t scan_base = 0;
  for (std::size_t part = 0; part < parts.size(); ++part) {
    Cloud& c = parts[part];
    const Eigen::Index n = c.xyz.cols();
    all.xyz.middleCols(at, n) = c.xyz;
    c.xyz = Eigen::Matrix3Xd();
    const auto take = [](auto& mine, auto& theirs, bool keep) {
      if (keep) mine.insert(mine.end(), theirs.begin(), theirs.end());
      std::decay_t<decltype(theirs)>().swap(theirs);
    };
    take(all.rgb, c.rgb, rgb);
    take(all.intensity, c.intensity, intensity);
    take(all.normal, c.normal, normals);
    take(all.curvature, c.curvature, curvature);
    take(all.row, c.row, grid_index);
    take(all.col, c.col, grid_index);
    if (scan_id) {
      for (Eigen::Index i = 0; i < n; ++i) {
        all.scan_id.push_back(static_cast<std::uint16_t>(scan_base + (c.has_scan_id() ? c.scan_id[static_cast<std::size_t>(i)] : 0)));
      }
    }
    scan_base += scans_of[part];
    for (auto tri : c.mesh.triangles) {
      for (auto& v : tri) v += static_cast<std::uint32_t>(at);
      all.mesh.triangles.push_back(tri);
    }
    if (texture && c.mesh.has_texture()) {
      all.mesh.corner_uv.insert(all.mesh.corner_uv.end(), c.mesh.corner_uv.begin(), c.mesh.corner_uv.end());
      all.mesh.texture = c.mesh.texture;
    }
    all.float32_xyz = all.float32_xyz || c.float32_xyz;  // any float-stored part limits the precision
    at += n;
  }
  all.crs = crs.first;
  report.figure("files", static_cast<double>(files.size()));
  report.count_in = report.count_out = all.size();
  report.seconds = seconds_since(t0);
  return {std::move(all), std::move(report)};
}

}  // namespace hc::pipeline
