#pragma once
// Image files of the pipeline (private to hc::pipeline, not installed): the scene's layers
// (32-bit float TIFF, 8-bit PNG), the previews (PNG) and the textures of OBJ meshes. Written on
// libpng, libtiff and stb_image (Debian's libpng16, libtiff6, libstb0) instead of OpenCV's image
// codecs, whose library loads about 140 others (GDAL, GDCM, libheif, ...) and cost every
// command about 60 ms of start-up (bench/README.md, "Start-up").

#include <cstddef>
#include <cstdint>
#include <functional>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace hc::pipeline::detail {

/// Channel layouts of 8-bit pixels: one byte per channel, channels interleaved, rows top to bottom.
enum class PixelFormat { kGray, kRgb, kBgr };

/// Writes an 8-bit PNG (PNG 1.2 / ISO 15948), row by row through libpng's full API. `row_stride`
/// is the distance between rows in bytes (0 = width × channels). Without `fast`: zlib level 6 and
/// adaptive row filters, and an sRGB chunk for colour, as libpng's simplified API writes. `fast`,
/// for previews: no row filters and zlib level 1 (about half the time of the simplified API's
/// PNG_IMAGE_FLAG_FAST, files about 10 % larger). `after_rows`, if set, is called after each
/// block of at least 4 MiB of rows and after the last (the scene's flags give a file-backed
/// layer's pages back by it, cell_buffer.hpp); it must not throw. A write that fails removes its
/// file. @return "" on success, else why not (libpng's message, or the system's for the file).
std::string write_png(const std::filesystem::path& file, const std::uint8_t* pixels, int width, int height,
                      PixelFormat format, std::size_t row_stride = 0, bool fast = false,
                      const std::function<void()>& after_rows = {});

/// The same PNG in memory. @return the bytes; empty on failure, with *error set.
std::vector<std::uint8_t> encode_png(const std::uint8_t* pixels, int width, int height, PixelFormat format,
                                     std::string* error);

/// An 8-bit image read from a file.
struct Image8 {
  int width = 0, height = 0;
  int channels = 0;                  ///< 1 (gray) or 3 (RGB)
  std::vector<std::uint8_t> pixels;  ///< rows top to bottom, channels interleaved
  bool converted = false;            ///< read_png: the file's own format was another (converted)
};

/// Reads a PNG as 8-bit gray (format kGray) or RGB (kRgb) with libpng's simplified API, which
/// converts other PNG colour types and 16-bit samples. @return "" and `out`, or why not.
std::string read_png(const std::filesystem::path& file, PixelFormat format, Image8& out);

/// Reads any image stb_image decodes (PNG, JPEG baseline and progressive, BMP, TGA, GIF, PSD,
/// HDR, PIC, PNM) as 8-bit RGB. @return "" and `out`, or stb_image's reason.
std::string read_rgb_image(const std::filesystem::path& file, Image8& out);

/// Writes a single-channel 32-bit IEEE float TIFF (libtiff; TIFF 6.0 with SampleFormat 3),
/// uncompressed, in strips of about 64 KiB (deflate with the floating-point predictor made the
/// Buddha's N = 4096 scene 2.6× smaller but its write stage 1.9× slower: 1.81 s against 0.94 s,
/// 2026-11-23). @return "" on success, else why not.
std::string write_float_tiff(const std::filesystem::path& file, const float* values, int width, int height);

/// A single-channel 32-bit float image read from a TIFF (strips or tiles, any compression
/// libtiff decodes: the scenes written by earlier versions through OpenCV included).
struct FloatImage {
  int width = 0, height = 0;
  std::vector<float> values;  ///< rows top to bottom
};
/// `expected_width` × `expected_height` (> 0): any other size is refused before anything is
/// allocated. @return "" and `out`, or why not (not a TIFF, not one float channel, another
/// size, a libtiff error).
std::string read_float_tiff(const std::filesystem::path& file, FloatImage& out, int expected_width, int expected_height);

/// Samples of a tiled TIFF: one 32-bit IEEE float channel, or 8-bit RGB (3 samples, contiguous).
enum class TileSamples { kFloat32, kRgb8 };

/// Bytes per sample position of `s` (4 or 3).
inline int tile_sample_bytes(TileSamples s) { return s == TileSamples::kFloat32 ? 4 : 3; }

/// A tiled TIFF written tile by tile (TIFF 6.0 Section 15 "Tiled Images": TileWidth,
/// TileLength, TileOffsets, TileByteCounts; libtiff's TIFFWriteEncodedTile), uncompressed;
/// BigTIFF when the image passes 3.5 GB. A float tile whose samples are all NaN, or an RGB tile
/// that is never written, is left sparse: its TileByteCounts entry stays 0 (the convention of
/// GDAL's SPARSE_OK), so a scan's no-data areas cost no disk. TiledTiffReader gives NaN (float)
/// or 0 (RGB) for such a tile. Not thread-safe (one writer per thread).
class TiledTiffWriter {
 public:
  TiledTiffWriter();
  ~TiledTiffWriter();  ///< closes the file (a file not finished is left incomplete: callers stage)
  TiledTiffWriter(const TiledTiffWriter&) = delete;
  TiledTiffWriter& operator=(const TiledTiffWriter&) = delete;
  /// Creates `file` for a width × height image in tiles of tile × tile samples (tile a multiple
  /// of 16, as the TIFF specification requires, at most 4096). A float file carries GDAL's
  /// no-data tag (42113) "nan", so GDAL-based tools read tiles without bytes as no data.
  /// Memory: libtiff's write buffer of one tile per open file; the copy each write_tile makes
  /// is one scratch tile per thread. @return "" or why not.
  std::string open(const std::filesystem::path& file, int width, int height, int tile, TileSamples samples);
  /// Writes tile (tile_row, tile_col): tile × tile samples, row-major (× 3 bytes for RGB);
  /// samples beyond the image's edge are written as given and ignored by readers.
  /// @return "" or why not.
  std::string write_tile(int tile_row, int tile_col, const void* data);
  /// Writes the directory and closes the file. @return "" or why not.
  std::string finish();
  /// Bytes of tile data written so far (sparse tiles count 0).
  std::uint64_t bytes_written() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Copies the part of tile (tile_row, tile_col) of a tiled image that falls inside the rows × cols
/// rectangle at (row0, col0) into `out` (row-major, rows·cols samples of `samples`). `tile_data`
/// holds the tile's tile² samples, row-major, or is null for a tile without bytes: NaN (float) or
/// 0 (RGB) are written instead. The assembly step shared by TiledTiffReader::read_region and
/// the stored pyramid's tile cache. The caller passes only tiles that overlap the rectangle.
void copy_tile_part(const std::uint8_t* tile_data, int tile_row, int tile_col, int tile, TileSamples samples, int row0,
                    int col0, int rows, int cols, void* out);

/// Writes a whole image (rows top to bottom, `values` width·height samples, × 3 bytes for RGB)
/// as a tiled TIFF through TiledTiffWriter (sparse all-NaN float tiles), calling
/// `after_tile_row` (when set) once each row of tiles is written (a file-backed layer gives its
/// pages back there: cell_buffer.hpp). @return "" or why not.
std::string write_tiled_tiff(const std::filesystem::path& file, const void* values, int width, int height, int tile,
                             TileSamples samples, const std::function<void()>& after_tile_row = {});

/// Reads rectangles of a tiled TIFF written by TiledTiffWriter (or any uncompressed or
/// libtiff-decodable tiled TIFF of one float channel or 8-bit RGB), one tile at a time; only the
/// tiles a rectangle touches are read. The tile offsets are loaded on demand (libtiff's "O"
/// open mode), so opening costs the directory only, whatever the image's size.
/// Thread-safe: calls are serialised by a mutex (libtiff handles are not shared across threads).
class TiledTiffReader {
 public:
  TiledTiffReader();
  ~TiledTiffReader();
  TiledTiffReader(const TiledTiffReader&) = delete;
  TiledTiffReader& operator=(const TiledTiffReader&) = delete;
  /// Opens `file`, expecting `samples`. @return "" or why not (not a TIFF, not tiled, another
  /// sample type, tiles that are not square or larger than 4096 samples, an image wider or
  /// taller than 2^30 samples). Nothing is allocated from the file's sizes before they are checked.
  std::string open(const std::filesystem::path& file, TileSamples samples);
  int width() const;
  int height() const;
  int tile() const;  ///< tile side [samples] (square tiles)
  /// Copies rows × cols samples from (row0, col0) into `out` (row-major, rows·cols samples, × 3
  /// bytes for RGB); sparse tiles read as NaN (float) or 0 (RGB). The rectangle must lie inside
  /// the image. @return "" or why not (a libtiff read error during this call).
  std::string read_region(int row0, int col0, int rows, int cols, void* out) const;
  /// Decodes tile (tile_row, tile_col) whole into `out` (tile()² samples, × 3 bytes for RGB;
  /// samples past the image's edge as stored). A tile without bytes is not read: `*sparse` is set
  /// and `out` is left as it is. @return "" or why not (a tile outside the image, a libtiff read
  /// error during this call).
  std::string read_tile(int tile_row, int tile_col, void* out, bool* sparse) const;
  /// Tiles with data decoded so far (sparse tiles not counted), for tests and benchmarks.
  std::uint64_t tiles_read() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hc::pipeline::detail
