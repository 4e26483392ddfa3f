# Every package here comes from Debian 12 (see scripts/install-deps).
find_package(Threads REQUIRED)
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
# Debian's PCLConfig needs MPI's C component found first (see docs/architecture.md).
find_package(MPI REQUIRED COMPONENTS C)
# surface (MovingLeastSquares) and segmentation (EuclideanClusterExtraction): filters.pcl (issue 18).
find_package(PCL 1.13 REQUIRED COMPONENTS common io kdtree search filters surface segmentation)
# imgcodecs only for the tests (they read back what the pipeline writes); the pipeline itself
# writes and reads images with libpng, libtiff and stb_image (pipeline/src/image_io.hpp).
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc imgcodecs)
find_package(PNG REQUIRED)   # libpng-dev
find_package(TIFF 4.5 REQUIRED)  # libtiff-dev (4.5: per-file error handlers, TIFFOpenExt)
find_path(HC_STB_INCLUDE_DIR stb/stb_image.h REQUIRED)  # libstb-dev
find_library(HC_STB_LIBRARY stb REQUIRED)
find_package(yaml-cpp REQUIRED)
find_package(CLI11 REQUIRED)
find_package(spdlog REQUIRED)
find_package(nlohmann_json 3 REQUIRED)
find_package(nanoflann REQUIRED)
find_package(ZLIB REQUIRED)
find_package(PkgConfig REQUIRED)
pkg_check_modules(LIBDEFLATE REQUIRED IMPORTED_TARGET libdeflate)  # libdeflate-dev: gzip inflate of scans
find_package(OpenSSL REQUIRED COMPONENTS Crypto)
find_package(pugixml REQUIRED)  # E57 XML section (libpugixml-dev)
find_package(GDAL CONFIG REQUIRED)  # GeoTIFF export (libgdal-dev)
if(HC_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(HC_BUILD_BENCH)
  find_package(benchmark REQUIRED)
endif()
# Device, viewer and audio modules (issues 5, 6, 7).
find_package(PkgConfig REQUIRED)
pkg_check_modules(LIBUSB REQUIRED IMPORTED_TARGET libusb-1.0)
find_package(OpenGL REQUIRED COMPONENTS OpenGL)
find_package(glfw3 3.3 REQUIRED)
# Debian's libimgui-dev ships the core as a static library and the GLFW / OpenGL 3 backends as
# sources under its documentation folder; hc::viewer compiles those two backend files.
pkg_check_modules(IMGUI REQUIRED IMPORTED_TARGET imgui)
set(HC_IMGUI_BACKENDS_DIR /usr/share/doc/libimgui-dev/examples/backends
    CACHE PATH "Folder holding imgui_impl_glfw.cpp and imgui_impl_opengl3.cpp (libimgui-dev)")
find_package(OpenAL REQUIRED)
pkg_check_modules(SNDFILE REQUIRED IMPORTED_TARGET sndfile)
