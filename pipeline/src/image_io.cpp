// Image files on libpng, libtiff and stb_image (image_io.hpp).

#include "image_io.hpp"

#include <png.h>
#include <stb/stb_image.h>
#include <tiffio.h>

#include <algorithm>
#include <cmath>
#include <cerrno>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <system_error>

namespace hc::pipeline::detail {
namespace {

png_uint_32 png_format(PixelFormat f) {
  switch (f) {
    case PixelFormat::kGray: return PNG_FORMAT_GRAY;
    case PixelFormat::kRgb: return PNG_FORMAT_RGB;
    case PixelFormat::kBgr: return PNG_FORMAT_BGR;
  }
  return PNG_FORMAT_GRAY;
}

int channels_of(PixelFormat f) { return f == PixelFormat::kGray ? 1 : 3; }

png_image png_image_for(int width, int height, PixelFormat format) {
  png_image image;
  std::memset(&image, 0, sizeof image);
  image.version = PNG_IMAGE_VERSION;
  image.width = static_cast<png_uint_32>(width);
  image.height = static_cast<png_uint_32>(height);
  image.format = png_format(format);
  return image;
}

std::string png_message(const png_image& image, const char* fallback) {
  return image.message[0] != '\0' ? std::string(image.message) : std::string(fallback);
}

// libtiff's messages for one file, collected instead of printed (per-handle handlers, libtiff
// 4.5: thread-safe, unlike the global ones).
struct TiffMessages {
  std::string error;
  static int on_error(TIFF*, void* user, const char* module, const char* fmt, va_list ap) {
    auto* self = static_cast<TiffMessages*>(user);
    char text[512];
    std::vsnprintf(text, sizeof text, fmt, ap);
    if (self->error.empty()) self->error = std::string(module ? module : "libtiff") + ": " + text;
    return 1;
  }
  static int on_warning(TIFF*, void*, const char*, const char*, va_list) { return 1; }  // not errors
};

using TiffHandle = std::unique_ptr<TIFF, void (*)(TIFF*)>;

TiffHandle open_tiff(const std::filesystem::path& file, const char* mode, TiffMessages& messages) {
  std::unique_ptr<TIFFOpenOptions, void (*)(TIFFOpenOptions*)> options(TIFFOpenOptionsAlloc(), &TIFFOpenOptionsFree);
  TIFFOpenOptionsSetErrorHandlerExtR(options.get(), &TiffMessages::on_error, &messages);
  TIFFOpenOptionsSetWarningHandlerExtR(options.get(), &TiffMessages::on_warning, &messages);
  return TiffHandle(TIFFOpenExt(file.c_str(), mode, options.get()), &TIFFClose);
}

// The image layout tags of a TIFF, with libtiff's defaults where a tag is absent.
struct TiffLayout {
  std::uint32_t width = 0, height = 0;
  std::uint16_t samples = 1, bits = 0, format = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG;
};
TiffLayout layout_of(TIFF* t) {
  TiffLayout l;
  TIFFGetField(t, TIFFTAG_IMAGEWIDTH, &l.width);
  TIFFGetField(t, TIFFTAG_IMAGELENGTH, &l.height);
  TIFFGetFieldDefaulted(t, TIFFTAG_SAMPLESPERPIXEL, &l.samples);
  TIFFGetFieldDefaulted(t, TIFFTAG_BITSPERSAMPLE, &l.bits);
  TIFFGetFieldDefaulted(t, TIFFTAG_SAMPLEFORMAT, &l.format);
  TIFFGetFieldDefaulted(t, TIFFTAG_PLANARCONFIG, &l.planar);
  return l;
}

std::string tiff_failure(const TiffMessages& m, const char* fallback) {
  if (!m.error.empty()) return m.error;
  return errno != 0 ? std::string(std::strerror(errno)) : std::string(fallback);
}

// libpng's error message for one write, kept for the caller (libpng then longjmps back).
struct PngError {
  char text[256] = "libpng cannot write it";
};
void on_png_error(png_structp png, png_const_charp message) {
  auto* e = static_cast<PngError*>(png_get_error_ptr(png));
  std::snprintf(e->text, sizeof e->text, "%s", message ? message : "libpng error");
  png_longjmp(png, 1);
}
void on_png_warning(png_structp, png_const_charp) {}  // not errors

// PNG through libpng's full API, row by row. `fast` (the previews): zlib level 1 and no row
// filters, about half the time of the simplified API's PNG_IMAGE_FLAG_FAST for files about 10 %
// larger (a 330 × 844 hillshade: 15.2 → 6.9 ms, 238 → 261 kB). Otherwise libpng's defaults (zlib
// level 6, adaptive filters) and, for colour, the sRGB chunk, as its simplified API writes.
// `after_rows`, if set, is called after each block of rows of at least kRowBlockBytes and after
// the last row (it must not throw: libpng's frames lie between). Only trivially destructible
// objects live between setjmp and the writes (libpng longjmps on error). Returns 0 or a message
// in *error.
constexpr std::size_t kRowBlockBytes = std::size_t{4} << 20;
int write_png_rows(std::FILE* fp, const std::uint8_t* pixels, int width, int height, PixelFormat format,
                   std::size_t stride, bool fast, const std::function<void()>* after_rows, PngError* error) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, error, &on_png_error, &on_png_warning);
  if (png == nullptr) return 1;
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_write_struct(&png, nullptr);
    return 1;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return 1;
  }
  png_init_io(png, fp);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
               format == PixelFormat::kGray ? PNG_COLOR_TYPE_GRAY : PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  if (fast) {
    png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_NONE);
    png_set_compression_level(png, 1);
  } else if (format != PixelFormat::kGray) {
    png_set_sRGB(png, info, PNG_sRGB_INTENT_PERCEPTUAL);  // colour tagged as the simplified API tags it
  }
  png_write_info(png, info);
  if (format == PixelFormat::kBgr) png_set_bgr(png);
  std::size_t block = 0;
  for (int r = 0; r < height; ++r) {
    png_write_row(png, pixels + static_cast<std::size_t>(r) * stride);
    block += stride;
    if (after_rows != nullptr && *after_rows && (block >= kRowBlockBytes || r + 1 == height)) {
      (*after_rows)();
      block = 0;
    }
  }
  png_write_end(png, info);
  png_destroy_write_struct(&png, &info);
  return 0;
}

}  // namespace

std::string write_png(const std::filesystem::path& file, const std::uint8_t* pixels, int width, int height,
                      PixelFormat format, std::size_t row_stride, bool fast, const std::function<void()>& after_rows) {
  if (width < 1 || height < 1) return "an empty image";
  const std::size_t stride = row_stride ? row_stride : static_cast<std::size_t>(width * channels_of(format));
  std::FILE* fp = std::fopen(file.c_str(), "wb");
  if (fp == nullptr) return std::strerror(errno);
  PngError error;
  const int failed = write_png_rows(fp, pixels, width, height, format, stride, fast, &after_rows, &error);
  const bool closed = std::fclose(fp) == 0;
  const int close_errno = errno;
  if (!failed && closed) return {};
  // Nothing half-written is left.
  std::error_code ec;
  if (std::filesystem::is_regular_file(file, ec)) std::filesystem::remove(file, ec);
  if (failed) return error.text;
  return std::string("closing the file: ") + std::strerror(close_errno);
}

std::vector<std::uint8_t> encode_png(const std::uint8_t* pixels, int width, int height, PixelFormat format,
                                     std::string* error) {
  std::vector<std::uint8_t> bytes;
  if (width < 1 || height < 1) {
    *error = "an empty image";
    return bytes;
  }
  png_image image = png_image_for(width, height, format);
  png_alloc_size_t size = 0;
  const auto stride = static_cast<png_int_32>(width * channels_of(format));
  // First the size, then the bytes (libpng's two-call protocol).
  if (png_image_write_to_memory(&image, nullptr, &size, 0, pixels, stride, nullptr) == 0) {
    *error = png_message(image, "libpng cannot encode it");
    png_image_free(&image);
    return bytes;
  }
  bytes.resize(size);
  if (png_image_write_to_memory(&image, bytes.data(), &size, 0, pixels, stride, nullptr) == 0) {
    *error = png_message(image, "libpng cannot encode it");
    png_image_free(&image);
    bytes.clear();
    return bytes;
  }
  bytes.resize(size);
  return bytes;
}

std::string read_png(const std::filesystem::path& file, PixelFormat format, Image8& out) {
  png_image image;
  std::memset(&image, 0, sizeof image);
  image.version = PNG_IMAGE_VERSION;
  if (png_image_begin_read_from_file(&image, file.c_str()) == 0) return png_message(image, "not a PNG libpng reads");
  const png_uint_32 requested = png_format(format == PixelFormat::kBgr ? PixelFormat::kRgb : format);
  const bool converted = image.format != requested;  // colour map, alpha, 16 bit or another colour type
  image.format = requested;
  // 16-bit samples are sRGB-encoded like 8-bit ones (not linear): scaled, not gamma-mapped.
  image.flags |= PNG_IMAGE_FLAG_16BIT_sRGB;
  out = Image8();
  out.converted = converted;
  out.width = static_cast<int>(image.width);
  out.height = static_cast<int>(image.height);
  out.channels = channels_of(format);
  out.pixels.resize(PNG_IMAGE_SIZE(image));
  if (png_image_finish_read(&image, nullptr, out.pixels.data(), 0, nullptr) == 0) {
    const std::string why = png_message(image, "libpng cannot decode it");
    png_image_free(&image);
    out = Image8();
    return why;
  }
  return {};
}

std::string read_rgb_image(const std::filesystem::path& file, Image8& out) {
  int w = 0, h = 0, n = 0;
  std::unique_ptr<stbi_uc, void (*)(void*)> data(stbi_load(file.c_str(), &w, &h, &n, 3), &stbi_image_free);
  if (!data) {
    const char* why = stbi_failure_reason();
    return why ? std::string(why) : std::string("stb_image cannot decode it");
  }
  out = Image8();
  out.width = w;
  out.height = h;
  out.channels = 3;
  out.pixels.assign(data.get(), data.get() + 3 * static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
  return {};
}

std::string write_float_tiff(const std::filesystem::path& file, const float* values, int width, int height) {
  if (width < 1 || height < 1) return "an empty layer";
  TiffMessages messages;
  errno = 0;
  // BigTIFF ("w8") beyond what classic TIFF's 32-bit offsets hold.
  const bool big = static_cast<double>(width) * static_cast<double>(height) * sizeof(float) > 3.5e9;
  TiffHandle tif = open_tiff(file, big ? "w8" : "w", messages);
  if (!tif) return tiff_failure(messages, "libtiff cannot create it");
  TIFF* t = tif.get();
  const auto rows_per_strip =
      static_cast<std::uint32_t>(std::max(1, 65536 / static_cast<int>(sizeof(float) * static_cast<std::size_t>(width))));
  const bool tags = TIFFSetField(t, TIFFTAG_IMAGEWIDTH, static_cast<std::uint32_t>(width)) &&
                    TIFFSetField(t, TIFFTAG_IMAGELENGTH, static_cast<std::uint32_t>(height)) &&
                    TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, 1) && TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, 32) &&
                    TIFFSetField(t, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_IEEEFP) &&
                    TIFFSetField(t, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK) &&
                    TIFFSetField(t, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG) &&
                    TIFFSetField(t, TIFFTAG_COMPRESSION, COMPRESSION_NONE) &&
                    TIFFSetField(t, TIFFTAG_ROWSPERSTRIP, rows_per_strip);
  if (!tags) return tiff_failure(messages, "libtiff refused a tag");
  // libtiff may modify the buffer it is given (byte order, codecs): each strip is copied first.
  std::vector<float> strip;
  for (std::uint32_t row = 0, s = 0; row < static_cast<std::uint32_t>(height); row += rows_per_strip, ++s) {
    const std::uint32_t n = std::min(rows_per_strip, static_cast<std::uint32_t>(height) - row);
    strip.assign(values + static_cast<std::size_t>(row) * static_cast<std::size_t>(width),
                 values + static_cast<std::size_t>(row + n) * static_cast<std::size_t>(width));
    errno = 0;
    if (TIFFWriteEncodedStrip(t, s, strip.data(), static_cast<tmsize_t>(strip.size() * sizeof(float))) < 0) {
      return tiff_failure(messages, "libtiff cannot write a strip");
    }
  }
  errno = 0;
  if (!TIFFWriteDirectory(t)) return tiff_failure(messages, "libtiff cannot write the directory");
  TIFFFlush(t);
  if (!messages.error.empty()) return messages.error;
  return {};
}

std::string read_float_tiff(const std::filesystem::path& file, FloatImage& out, int expected_width, int expected_height) {
  TiffMessages messages;
  errno = 0;
  TiffHandle tif = open_tiff(file, "r", messages);
  if (!tif) return tiff_failure(messages, "not a TIFF libtiff reads");
  TIFF* t = tif.get();
  const TiffLayout layout = layout_of(t);
  const std::uint32_t width = layout.width, height = layout.height;
  const std::uint16_t samples = layout.samples, bits = layout.bits, format = layout.format;
  if (width == 0 || height == 0 || samples != 1 || bits != 32 || format != SAMPLEFORMAT_IEEEFP) {
    return std::to_string(width) + "x" + std::to_string(height) + ", " + std::to_string(samples) + " channel(s) of " +
           std::to_string(bits) + "-bit " + (format == SAMPLEFORMAT_IEEEFP ? "float" : "integer") + " samples";
  }
  if (width != static_cast<std::uint32_t>(expected_width) || height != static_cast<std::uint32_t>(expected_height)) {
    return std::to_string(width) + "x" + std::to_string(height);
  }
  out = FloatImage();
  out.width = static_cast<int>(width);
  out.height = static_cast<int>(height);
  out.values.assign(static_cast<std::size_t>(width) * height, 0.0f);
  if (TIFFIsTiled(t)) {
    std::uint32_t tw = 0, th = 0;
    TIFFGetField(t, TIFFTAG_TILEWIDTH, &tw);
    TIFFGetField(t, TIFFTAG_TILELENGTH, &th);
    if (tw == 0 || th == 0) return "tiled TIFF without tile sizes";
    // Bounded before the tile buffer is allocated from them (TiledTiffWriter writes at most 4096).
    if (tw > 4096 || th > 4096) return "tiles of " + std::to_string(tw) + "x" + std::to_string(th) + " (at most 4096 supported)";
    std::vector<float> tile(static_cast<std::size_t>(tw) * th);
    for (std::uint32_t y = 0; y < height; y += th)
      for (std::uint32_t x = 0; x < width; x += tw) {
        // A sparse tile (no bytes: TiledTiffWriter's all-NaN tiles) is no data.
        if (TIFFGetStrileByteCount(t, TIFFComputeTile(t, x, y, 0, 0)) == 0) {
          std::fill(tile.begin(), tile.end(), std::numeric_limits<float>::quiet_NaN());
        } else if (TIFFReadTile(t, tile.data(), x, y, 0, 0) < 0) {
          return tiff_failure(messages, "libtiff cannot read a tile");
        }
        for (std::uint32_t r = 0; r < th && y + r < height; ++r) {
          const std::uint32_t n = std::min(tw, width - x);
          std::copy_n(tile.data() + static_cast<std::size_t>(r) * tw, n,
                      out.values.data() + static_cast<std::size_t>(y + r) * width + x);
        }
      }
  } else {
    std::uint32_t rows_per_strip = height;
    TIFFGetFieldDefaulted(t, TIFFTAG_ROWSPERSTRIP, &rows_per_strip);
    rows_per_strip = std::clamp<std::uint32_t>(rows_per_strip, 1, height);
    const tstrip_t strips = TIFFNumberOfStrips(t);
    for (tstrip_t s = 0; s < strips; ++s) {
      const std::uint64_t row = static_cast<std::uint64_t>(s) * rows_per_strip;
      if (row >= height) break;
      const std::uint64_t n = std::min<std::uint64_t>(rows_per_strip, height - row);
      const auto bytes = static_cast<tmsize_t>(n * width * sizeof(float));
      if (TIFFReadEncodedStrip(t, s, out.values.data() + row * width, bytes) < 0) {
        return tiff_failure(messages, "libtiff cannot read a strip");
      }
    }
  }
  if (!messages.error.empty()) return messages.error;
  return {};
}

namespace {
bool all_nan(const float* v, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isnan(v[i])) return false;
  }
  return true;
}
}  // namespace

struct TiledTiffWriter::Impl {
  TiffMessages messages;
  TiffHandle tif{nullptr, &TIFFClose};
  int width = 0, height = 0, tile = 0;
  TileSamples samples = TileSamples::kFloat32;
  std::uint64_t bytes = 0;
};

TiledTiffWriter::TiledTiffWriter() : impl_(std::make_unique<Impl>()) {}
TiledTiffWriter::~TiledTiffWriter() = default;

std::string TiledTiffWriter::open(const std::filesystem::path& file, int width, int height, int tile,
                                  TileSamples samples) {
  if (width < 1 || height < 1) return "an empty layer";
  if (tile < 16 || tile > 4096 || tile % 16 != 0) {
    return "tile side " + std::to_string(tile) + " (expected a multiple of 16 in [16, 4096])";
  }
  Impl& m = *impl_;
  m.width = width;
  m.height = height;
  m.tile = tile;
  m.samples = samples;
  const int bps = tile_sample_bytes(samples);
  // BigTIFF ("w8") beyond what classic TIFF's 32-bit offsets hold (tiles padded to whole tiles).
  const double padded = std::ceil(width / static_cast<double>(tile)) * tile * std::ceil(height / static_cast<double>(tile)) *
                        tile * bps;
  errno = 0;
  m.tif = open_tiff(file, padded > 3.5e9 ? "w8" : "w", m.messages);
  if (!m.tif) return tiff_failure(m.messages, "libtiff cannot create it");
  TIFF* t = m.tif.get();
  const bool rgb = samples == TileSamples::kRgb8;
  // GDAL's no-data tag is not one libtiff registers itself: an ASCII tag, one value.
  static const TIFFFieldInfo kGdalNoData[] = {
      {TIFFTAG_GDAL_NODATA, TIFF_VARIABLE, TIFF_VARIABLE, TIFF_ASCII, FIELD_CUSTOM, 1, 0, const_cast<char*>("GDALNoDataValue")}};
  if (!rgb && TIFFMergeFieldInfo(t, kGdalNoData, 1) != 0) return tiff_failure(m.messages, "libtiff cannot register GDAL's no-data tag");
  const bool tags = TIFFSetField(t, TIFFTAG_IMAGEWIDTH, static_cast<std::uint32_t>(width)) &&
                    TIFFSetField(t, TIFFTAG_IMAGELENGTH, static_cast<std::uint32_t>(height)) &&
                    TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, rgb ? 3 : 1) &&
                    TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, rgb ? 8 : 32) &&
                    TIFFSetField(t, TIFFTAG_SAMPLEFORMAT, rgb ? SAMPLEFORMAT_UINT : SAMPLEFORMAT_IEEEFP) &&
                    TIFFSetField(t, TIFFTAG_PHOTOMETRIC, rgb ? PHOTOMETRIC_RGB : PHOTOMETRIC_MINISBLACK) &&
                    TIFFSetField(t, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG) &&
                    TIFFSetField(t, TIFFTAG_COMPRESSION, COMPRESSION_NONE) &&
                    TIFFSetField(t, TIFFTAG_TILEWIDTH, static_cast<std::uint32_t>(tile)) &&
                    TIFFSetField(t, TIFFTAG_TILELENGTH, static_cast<std::uint32_t>(tile)) &&
                    // GDAL's no-data tag (42113, ASCII): GDAL and the tools on it (QGIS, rasterio)
                    // fill a tile without bytes with this value, and mask it; without the tag they
                    // would read 0 m there.
                    (rgb || TIFFSetField(t, TIFFTAG_GDAL_NODATA, "nan"));
  if (!tags) return tiff_failure(m.messages, "libtiff refused a tag");
  return {};
}

std::string TiledTiffWriter::write_tile(int tile_row, int tile_col, const void* data) {
  Impl& m = *impl_;
  if (!m.tif) return "the tiled TIFF is not open";
  const std::size_t n = static_cast<std::size_t>(m.tile) * static_cast<std::size_t>(m.tile);
  if (m.samples == TileSamples::kFloat32 && all_nan(static_cast<const float*>(data), n)) return {};  // sparse
  // One scratch tile per thread, shared by every writer (a TiledSceneWriter has a file open per
  // layer and level): libtiff may modify the buffer it is given.
  thread_local std::vector<std::uint8_t> scratch;
  const std::size_t bytes = n * static_cast<std::size_t>(tile_sample_bytes(m.samples));
  scratch.resize(bytes);
  std::memcpy(scratch.data(), data, bytes);
  TIFF* t = m.tif.get();
  const ttile_t index = TIFFComputeTile(t, static_cast<std::uint32_t>(tile_col * m.tile),
                                        static_cast<std::uint32_t>(tile_row * m.tile), 0, 0);
  errno = 0;
  if (TIFFWriteEncodedTile(t, index, scratch.data(), static_cast<tmsize_t>(bytes)) < 0) {
    return tiff_failure(m.messages, "libtiff cannot write a tile");
  }
  m.bytes += bytes;
  return {};
}

std::string TiledTiffWriter::finish() {
  Impl& m = *impl_;
  if (!m.tif) return "the tiled TIFF is not open";
  errno = 0;
  if (!TIFFWriteDirectory(m.tif.get())) return tiff_failure(m.messages, "libtiff cannot write the directory");
  TIFFFlush(m.tif.get());
  m.tif.reset();
  if (!m.messages.error.empty()) return m.messages.error;
  return {};
}

std::uint64_t TiledTiffWriter::bytes_written() const { return impl_->bytes; }

std::string write_tiled_tiff(const std::filesystem::path& file, const void* values, int width, int height, int tile,
                             TileSamples samples, const std::function<void()>& after_tile_row) {
  TiledTiffWriter w;
  if (std::string why = w.open(file, width, height, tile, samples); !why.empty()) return why;
  const auto bps = static_cast<std::size_t>(tile_sample_bytes(samples));
  std::vector<std::uint8_t> block(static_cast<std::size_t>(tile) * static_cast<std::size_t>(tile) * bps);
  const auto* src = static_cast<const std::uint8_t*>(values);
  for (int tr = 0; tr * tile < height; ++tr) {
    for (int tc = 0; tc * tile < width; ++tc) {
      // Samples past the edge: NaN for floats (so an edge tile of no data stays sparse), 0 for RGB.
      if (samples == TileSamples::kFloat32) {
        std::fill_n(reinterpret_cast<float*>(block.data()), block.size() / 4, std::numeric_limits<float>::quiet_NaN());
      } else {
        std::fill(block.begin(), block.end(), std::uint8_t{0});
      }
      const int rows = std::min(tile, height - tr * tile);
      const int cols = std::min(tile, width - tc * tile);
      for (int r = 0; r < rows; ++r) {
        const std::size_t from = (static_cast<std::size_t>(tr * tile + r) * static_cast<std::size_t>(width) +
                                  static_cast<std::size_t>(tc * tile)) * bps;
        std::memcpy(block.data() + static_cast<std::size_t>(r) * static_cast<std::size_t>(tile) * bps, src + from,
                    static_cast<std::size_t>(cols) * bps);
      }
      if (std::string why = w.write_tile(tr, tc, block.data()); !why.empty()) return why;
    }
    if (after_tile_row) after_tile_row();
  }
  return w.finish();
}

struct TiledTiffReader::Impl {
  mutable TiffMessages messages;
  TiffHandle tif{nullptr, &TIFFClose};
  int width = 0, height = 0, tile = 0;
  TileSamples samples = TileSamples::kFloat32;
  mutable std::mutex mutex;
  mutable std::vector<std::uint8_t> buffer;
  mutable std::uint64_t tiles_read = 0;
};

TiledTiffReader::TiledTiffReader() : impl_(std::make_unique<Impl>()) {}
TiledTiffReader::~TiledTiffReader() = default;

std::string TiledTiffReader::open(const std::filesystem::path& file, TileSamples samples) {
  Impl& m = *impl_;
  errno = 0;
  // "O": the tile offsets and byte counts are read on demand, entry by entry (libtiff >= 4.1).
  // "m": no memory mapping: a mapped file's touched pages count in the process's resident memory
  // (a session reading windows of a 10 GB layer would show them all), so tiles are read(2) into
  // one tile buffer instead.
  m.tif = open_tiff(file, "rOm", m.messages);
  if (!m.tif) return tiff_failure(m.messages, "not a TIFF libtiff reads");
  TIFF* t = m.tif.get();
  if (!TIFFIsTiled(t)) return "not a tiled TIFF";
  const TiffLayout layout = layout_of(t);
  const std::uint32_t width = layout.width, height = layout.height;
  const std::uint16_t spp = layout.samples, bits = layout.bits, format = layout.format, planar = layout.planar;
  std::uint32_t tw = 0, th = 0;
  TIFFGetField(t, TIFFTAG_TILEWIDTH, &tw);
  TIFFGetField(t, TIFFTAG_TILELENGTH, &th);
  const bool want_float = samples == TileSamples::kFloat32;
  const bool ok = want_float ? (spp == 1 && bits == 32 && format == SAMPLEFORMAT_IEEEFP)
                             : (spp == 3 && bits == 8 && format == SAMPLEFORMAT_UINT && planar == PLANARCONFIG_CONTIG);
  if (!ok) {
    return std::to_string(spp) + " channel(s) of " + std::to_string(bits) + "-bit samples (expected " +
           (want_float ? "one 32-bit float channel" : "8-bit RGB") + ")";
  }
  // Bounds before anything is allocated from them: the buffer holds one tile (at most 4096², as
  // TiledTiffWriter writes: 64 MiB of floats).
  if (width == 0 || height == 0 || tw == 0 || tw != th || tw > 4096 || width > (1u << 30) || height > (1u << 30)) {
    return "a tiled TIFF of " + std::to_string(width) + "x" + std::to_string(height) + " in tiles of " +
           std::to_string(tw) + "x" + std::to_string(th) + " (expected square tiles of at most 4096 samples)";
  }
  m.width = static_cast<int>(width);
  m.height = static_cast<int>(height);
  m.tile = static_cast<int>(tw);
  m.samples = samples;
  // Allocated by read_region on first use (read_tile decodes into its caller's buffer).
  if (static_cast<std::size_t>(TIFFTileSize(t)) != static_cast<std::size_t>(tw) * th * static_cast<std::size_t>(tile_sample_bytes(samples))) {
    return "tile size " + std::to_string(TIFFTileSize(t)) + " bytes (expected " +
           std::to_string(static_cast<std::size_t>(tw) * th * static_cast<std::size_t>(tile_sample_bytes(samples))) + ")";
  }
  return {};
}

int TiledTiffReader::width() const { return impl_->width; }
int TiledTiffReader::height() const { return impl_->height; }
int TiledTiffReader::tile() const { return impl_->tile; }
std::uint64_t TiledTiffReader::tiles_read() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->tiles_read;
}

void copy_tile_part(const std::uint8_t* tile_data, int tile_row, int tile_col, int tile, TileSamples samples, int row0,
                    int col0, int rows, int cols, void* out) {
  const auto bps = static_cast<std::size_t>(tile_sample_bytes(samples));
  auto* dst = static_cast<std::uint8_t*>(out);
  const int r_begin = std::max(row0, tile_row * tile), r_end = std::min(row0 + rows, (tile_row + 1) * tile);
  const int c_begin = std::max(col0, tile_col * tile), c_end = std::min(col0 + cols, (tile_col + 1) * tile);
  if (r_begin >= r_end || c_begin >= c_end) return;
  const std::size_t run = static_cast<std::size_t>(c_end - c_begin) * bps;
  for (int r = r_begin; r < r_end; ++r) {
    std::uint8_t* to = dst + (static_cast<std::size_t>(r - row0) * static_cast<std::size_t>(cols) +
                              static_cast<std::size_t>(c_begin - col0)) * bps;
    if (tile_data == nullptr) {
      if (samples == TileSamples::kFloat32) {
        std::fill_n(reinterpret_cast<float*>(to), run / sizeof(float), std::numeric_limits<float>::quiet_NaN());
      } else {
        std::memset(to, 0, run);
      }
    } else {
      std::memcpy(to, tile_data + (static_cast<std::size_t>(r - tile_row * tile) * static_cast<std::size_t>(tile) +
                                   static_cast<std::size_t>(c_begin - tile_col * tile)) * bps, run);
    }
  }
}

std::string TiledTiffReader::read_tile(int tile_row, int tile_col, void* out, bool* sparse) const {
  const Impl& m = *impl_;
  if (!m.tif) return "the tiled TIFF is not open";
  if (tile_row < 0 || tile_col < 0 || tile_row >= (m.height + m.tile - 1) / m.tile ||
      tile_col >= (m.width + m.tile - 1) / m.tile) {
    return "tile (" + std::to_string(tile_row) + ", " + std::to_string(tile_col) + ") outside the " +
           std::to_string(m.height) + "x" + std::to_string(m.width) + " image";
  }
  std::lock_guard<std::mutex> lock(m.mutex);
  m.messages.error.clear();
  TIFF* t = m.tif.get();
  const ttile_t index = TIFFComputeTile(t, static_cast<std::uint32_t>(tile_col * m.tile),
                                        static_cast<std::uint32_t>(tile_row * m.tile), 0, 0);
  *sparse = TIFFGetStrileByteCount(t, index) == 0;
  if (*sparse) return m.messages.error;
  const auto bytes = static_cast<tmsize_t>(static_cast<std::size_t>(m.tile) * static_cast<std::size_t>(m.tile) *
                                           static_cast<std::size_t>(tile_sample_bytes(m.samples)));
  errno = 0;
  // Straight into the caller's tile (TIFFTileSize equals `bytes` for square tiles of one float or
  // three 8-bit samples, checked at open); a short decode is an error, never stale bytes.
  const tmsize_t got = TIFFReadEncodedTile(t, index, out, bytes);
  if (got < 0) return tiff_failure(m.messages, "libtiff cannot read a tile");
  if (got != bytes) {
    return "tile (" + std::to_string(tile_row) + ", " + std::to_string(tile_col) + ") decoded to " + std::to_string(got) +
           " bytes, expected " + std::to_string(bytes);
  }
  ++m.tiles_read;
  return m.messages.error;
}

std::string TiledTiffReader::read_region(int row0, int col0, int rows, int cols, void* out) const {
  const Impl& m = *impl_;
  if (!m.tif) return "the tiled TIFF is not open";
  if (rows < 1 || cols < 1 || row0 < 0 || col0 < 0 || row0 + rows > m.height || col0 + cols > m.width) {
    return "region " + std::to_string(rows) + "x" + std::to_string(cols) + " at (" + std::to_string(row0) + ", " +
           std::to_string(col0) + ") outside the " + std::to_string(m.height) + "x" + std::to_string(m.width) + " image";
  }
  std::lock_guard<std::mutex> lock(m.mutex);
  // Errors are this call's own: a corrupt tile read before does not fail every later window.
  m.messages.error.clear();
  TIFF* t = m.tif.get();
  const int tile = m.tile;
  if (m.buffer.empty()) m.buffer.resize(static_cast<std::size_t>(TIFFTileSize(t)));
  for (int tr = row0 / tile; tr * tile < row0 + rows; ++tr) {
    for (int tc = col0 / tile; tc * tile < col0 + cols; ++tc) {
      const ttile_t index = TIFFComputeTile(t, static_cast<std::uint32_t>(tc * tile), static_cast<std::uint32_t>(tr * tile), 0, 0);
      const bool sparse = TIFFGetStrileByteCount(t, index) == 0;
      if (!sparse) {
        errno = 0;
        if (TIFFReadEncodedTile(t, index, m.buffer.data(), static_cast<tmsize_t>(m.buffer.size())) < 0) {
          return tiff_failure(m.messages, "libtiff cannot read a tile");
        }
        ++m.tiles_read;
      }
      copy_tile_part(sparse ? nullptr : m.buffer.data(), tr, tc, tile, m.samples, row0, col0, rows, cols, out);
    }
  }
  if (!m.messages.error.empty()) return m.messages.error;
  return {};
}

}  // namespace hc::pipeline::detail
