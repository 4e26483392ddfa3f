# Installation and packaging (issue 17).
#   cmake --install build/release --prefix PREFIX
# installs the libraries (static), their public headers, the `hapticloud` program, the shipped
# configs, and PREFIX/lib/cmake/hapticloud/hapticloudConfig.cmake with the exported targets
# hapticloud::common, ::pipeline, ::pcl, ::haptics, ::falcon, ::session, ::audio, ::viewer (and
# the two settings-only targets ::audio_config and ::falcon_config they need), so another
# project does
#   find_package(hapticloud REQUIRED)
#   target_link_libraries(app PRIVATE hapticloud::pipeline)
# `cpack --config build/release/CPackConfig.cmake` makes a Debian package of the same tree.
# tests/install/ holds the consumer project the `install` test builds against an installed tree.
# Only when hapticloud is the top-level project (or HC_INSTALL=ON): pulled in by another
# project's add_subdirectory or FetchContent, it adds nothing to that project's install or package.
option(HC_INSTALL "Install rules and the CPack package" ${PROJECT_IS_TOP_LEVEL})
if(NOT HC_INSTALL)
  return()
endif()
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

# Module target → exported name. Targets a configuration did not build (no sources) are skipped.
set(HC_EXPORTED_MODULES common audio_config falcon_config pipeline pcl haptics falcon session audio viewer)
set(HC_INSTALLED_TARGETS "")
foreach(module IN LISTS HC_EXPORTED_MODULES)
  if(TARGET hc_${module})
    set_target_properties(hc_${module} PROPERTIES EXPORT_NAME ${module})
    list(APPEND HC_INSTALLED_TARGETS hc_${module})
  endif()
endforeach()
install(TARGETS ${HC_INSTALLED_TARGETS}
        EXPORT hapticloudTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
# Public headers: every module's include/ tree (hc/<module>/...).
foreach(dir common pipeline pcl_bridge haptics haptics/falcon session audio viewer)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/${dir}/include/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
          FILES_MATCHING PATTERN "*.hpp" PATTERN "*.h")
endforeach()
install(TARGETS hapticloud RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
# The GeoTIFF writer module (GDAL), loaded by the pipeline on the first export, and the PCL module
# (the PCD reader, filters.voxel_m, filters.pcl), loaded when a run first needs PCL.
install(TARGETS hc_geotiff_gdal LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}/hapticloud)
install(TARGETS hc_pcl_module LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}/hapticloud)
install(DIRECTORY ${PROJECT_SOURCE_DIR}/configs/ DESTINATION ${CMAKE_INSTALL_DATADIR}/hapticloud/configs
        FILES_MATCHING PATTERN "*.yaml")
install(FILES ${PROJECT_SOURCE_DIR}/udev/99-novint-falcon.rules
        DESTINATION ${CMAKE_INSTALL_DATADIR}/hapticloud/udev OPTIONAL)

set(HC_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/hapticloud)
install(EXPORT hapticloudTargets NAMESPACE hapticloud:: DESTINATION ${HC_CMAKE_DIR})
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/hapticloudConfig.cmake.in
                              ${PROJECT_BINARY_DIR}/hapticloudConfig.cmake
                              INSTALL_DESTINATION ${HC_CMAKE_DIR})
write_basic_package_version_file(${PROJECT_BINARY_DIR}/hapticloudConfigVersion.cmake
                                 VERSION ${PROJECT_VERSION} COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/hapticloudConfig.cmake ${PROJECT_BINARY_DIR}/hapticloudConfigVersion.cmake
        DESTINATION ${HC_CMAKE_DIR})

# Debian package (cpack -G DEB). The libraries are static: a program linking them needs the
# same -dev packages hapticloud builds with, which the package depends on.
set(CPACK_PACKAGE_NAME hapticloud)
set(CPACK_PACKAGE_VENDOR "hapticloud developers")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY
    "Hapto-visual and auditory rendering of scanned cultural-heritage objects (library, headers, program)")
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_GENERATOR DEB)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_MAINTAINER "hapticloud developers <hapticloud@localhost>")
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_DEPENDS
    "libpcl-dev (>= 1.13), libopencv-dev (>= 4), libeigen3-dev (>= 3.4), libyaml-cpp-dev, libspdlog-dev, nlohmann-json3-dev, libnanoflann-dev, zlib1g-dev, libdeflate-dev, libpng-dev, libtiff-dev (>= 4.5), libstb-dev, libssl-dev, libpugixml-dev, libgdal-dev, libusb-1.0-0-dev, libglfw3-dev, libimgui-dev, libopenal-dev, libsndfile1-dev, pkg-config, python3, python3-numpy")
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
include(CPack)
