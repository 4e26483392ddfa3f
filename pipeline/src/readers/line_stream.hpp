#pragma once
/// @file line_stream.hpp
/// What the text streams (PTX, PTS, XYZ, ASCII PLY; point_stream.hpp) share: a ByteSource read
/// in blocks of lines (FileLines), chunks filled by the format's parser, and the sticky failure
/// (StickyFailure, readers.hpp). Private to the pipeline.

#include "byte_source.hpp"
#include "text_lines.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/point_stream.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace hc::pipeline::detail {

class LineStream : public PointStream {
 public:
  std::uint64_t total_points() const override { return total_; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return true; }

  /// The next chunk: fill() parses up to max_points (≥ 1) points into xyz_, intensity_ and
  /// rgb_, shape() finishes the chunk. @throws hc::InputError as the parser (naming the file and
  /// line), and on every call after a failure.
  bool next(Cloud& chunk, std::size_t max_points) final {
    return sticky_.run(name_, chunk, [&] {
      xyz_.clear();
      intensity_.clear();
      rgb_.clear();
      fill(std::max<std::size_t>(max_points, 1));
      const std::size_t n = xyz_.size() / 3;
      if (n == 0) return false;
      chunk.xyz = Eigen::Map<const Eigen::Matrix3Xd>(xyz_.data(), 3, static_cast<Eigen::Index>(n));
      chunk.intensity = intensity_;
      chunk.rgb = rgb_;
      shape(chunk);
      return true;
    });
  }

 protected:
  /// `src` opened on the file (its name(), the quoted path, names the file in messages).
  explicit LineStream(std::unique_ptr<ByteSource> src) : src_(std::move(src)), name_(src_->name()) {}
  /// The lines from src_'s current position on (after a first look, or a header of
  /// `lines_before` lines: FileLines).
  void start_lines(bool skip_blank = true, std::size_t lines_before = 0) {
    lines_ = std::make_unique<FileLines>(*src_, skip_blank, lines_before);
  }
  /// The points a Parser<FileLines>(lines, name_).look() over the whole file counts, kept under
  /// `what` for later streams of the same unchanged large file (first_look); src_ then back at
  /// its start. @throws what the look throws (hc::InputError naming the file).
  template <template <class> class Parser>
  std::uint64_t points_by_look(const std::string& what) {
    return first_look(*src_, what, [&] {
      FileLines lines(*src_);
      return std::array<std::uint64_t, 2>{Parser<FileLines>(lines, name_).look(), 0};
    })[0];
  }
  /// Parses up to `max` points into xyz_ (x y z each), intensity_ and rgb_ (when the format
  /// has them); at the end of the file, fewer or none, and the end's checks.
  virtual void fill(std::size_t max) = 0;
  /// Finishes a chunk that holds points (a flag, colour dropped, the notes so far).
  virtual void shape(Cloud&) {}

  std::unique_ptr<ByteSource> src_;
  std::string name_;
  std::unique_ptr<FileLines> lines_;
  std::uint64_t total_ = 0;
  std::vector<std::string> notes_;
  std::vector<double> xyz_;
  std::vector<float> intensity_;
  std::vector<std::uint8_t> rgb_;

 private:
  StickyFailure sticky_;
};

}  // namespace hc::pipeline::detail
