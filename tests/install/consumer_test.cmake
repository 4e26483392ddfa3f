# The `install` test (issue 17): installs the build tree into a fresh prefix, configures and
# builds tests/install/consumer against it with find_package(hapticloud), and runs the consumer
# on the installed sinusoid config (it checks the scene against the analytic surface). Also runs
# the installed program and makes the Debian package with cpack. Fails with the failing step's output.
#   cmake -DHC_BINARY_DIR=... -DHC_SOURCE_DIR=... -DWORK=... -DCXX=... -DCXX_FLAGS=...
#         -DLINKER_FLAGS=... -DBUILD_TYPE=... -DGENERATOR=... -DVERSION=... -DCPACK=... -P consumer_test.cmake
foreach(v HC_BINARY_DIR HC_SOURCE_DIR WORK CXX GENERATOR VERSION CPACK)
  if(NOT DEFINED ${v} OR "${${v}}" STREQUAL "")
    message(FATAL_ERROR "consumer_test.cmake: -D${v}=... is required")
  endif()
endforeach()

function(step name)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "install test: ${name} failed (${rc}):\n${out}\n${err}")
  endif()
  message(STATUS "install test: ${name}: ok")
  set(step_output "${out}" PARENT_SCOPE)
endfunction()

file(REMOVE_RECURSE "${WORK}")
file(MAKE_DIRECTORY "${WORK}")
set(prefix "${WORK}/prefix")
step("cmake --install" ${CMAKE_COMMAND} --install "${HC_BINARY_DIR}" --prefix "${prefix}")
foreach(f lib/cmake/hapticloud/hapticloudConfig.cmake lib/cmake/hapticloud/hapticloudTargets.cmake
          include/hc/common/height_field.hpp include/hc/pipeline/run.hpp bin/hapticloud
          share/hapticloud/configs/sinusoid.yaml)
  if(NOT EXISTS "${prefix}/${f}")
    message(FATAL_ERROR "install test: ${prefix}/${f} was not installed")
  endif()
endforeach()
step("the installed program" "${prefix}/bin/hapticloud" --version)
if(NOT step_output MATCHES "hapticloud")
  message(FATAL_ERROR "install test: `hapticloud --version` printed: ${step_output}")
endif()
# The installed program finds the installed GeoTIFF module (GDAL is loaded only to export).
if(NOT EXISTS "${prefix}/${LIBDIR}/hapticloud/hc_geotiff_gdal.so")
  message(FATAL_ERROR "install test: ${prefix}/${LIBDIR}/hapticloud/hc_geotiff_gdal.so was not installed")
endif()
step("the installed program runs a config" "${prefix}/bin/hapticloud" run "${prefix}/share/hapticloud/configs/sinusoid.yaml"
     --out "${WORK}/run" --set lod.report=false)
# Started by name from $PATH (argv[0] is then a bare name), as users start it.
step("the installed program exports a GeoTIFF" ${CMAKE_COMMAND} -E env "PATH=${prefix}/bin:$ENV{PATH}"
     hapticloud export "${WORK}/run/scene" --format geotiff --out "${WORK}/depth.tif")
file(REAL_PATH "${prefix}/${LIBDIR}/hapticloud/hc_geotiff_gdal.so" installed_module)
string(FIND "${step_output}" "written through ${installed_module}" at)
if(at EQUAL -1)
  message(FATAL_ERROR "install test: the installed program did not load the installed module: ${step_output}")
endif()
step("configure the consumer" ${CMAKE_COMMAND} -S "${HC_SOURCE_DIR}/tests/install/consumer" -B "${WORK}/build"
     -G "${GENERATOR}" "-DCMAKE_PREFIX_PATH=${prefix}" "-DCMAKE_CXX_COMPILER=${CXX}"
     "-DCMAKE_BUILD_TYPE=${BUILD_TYPE}" "-DCMAKE_CXX_FLAGS=${CXX_FLAGS}" "-DCMAKE_EXE_LINKER_FLAGS=${LINKER_FLAGS}")
step("build the consumer" ${CMAKE_COMMAND} --build "${WORK}/build")
step("run the consumer" "${WORK}/build/consumer" "${prefix}/share/hapticloud/configs/sinusoid.yaml")
message(STATUS "${step_output}")

# The Python package of the installed tree (when the build has it): importable from the prefix.
if(DEFINED PYTHON AND NOT PYTHON STREQUAL "")
  file(GLOB py_dirs "${prefix}/lib/python3*/dist-packages")
  set(ENV{PYTHONPATH} "${py_dirs}")
  # A script file: CMake would split a -c string at its semicolons.
  file(WRITE "${WORK}/import_test.py" [=[
import sys
import hapticloud
cfg = {"name": "p", "input": {"synthetic": {"surface": "plane", "half_extent_m": 0.01, "density_per_m2": 1e6}},
       "filters": {"outliers": {"enabled": False}}, "grid": {"n": 20}, "lod": {"report": False}}
s = hapticloud.run(cfg)
print(hapticloud.__file__, s.rows, s.cols)
sys.exit(0 if s.layers["depth"].shape == (s.rows, s.cols) and s.cols == 20 else 1)
]=])
  step("import the installed Python package" "${PYTHON}" "${WORK}/import_test.py")
  if(NOT step_output MATCHES "${prefix}")
    message(FATAL_ERROR "install test: the imported hapticloud is not the installed one: ${step_output}")
  endif()
endif()

# The Debian package of the same tree: its file list holds the config, a library, a header and
# the program under /usr, and its control file the version and the -dev packages it needs.
step("cpack -G DEB" ${CMAKE_COMMAND} -E chdir "${WORK}" ${CPACK} -G DEB --config "${HC_BINARY_DIR}/CPackConfig.cmake"
     -B "${WORK}/package")
file(GLOB debs "${WORK}/package/hapticloud_*.deb")
list(LENGTH debs n_debs)
if(NOT n_debs EQUAL 1)
  message(FATAL_ERROR "install test: expected one hapticloud_*.deb in ${WORK}/package, found: ${debs}")
endif()
step("dpkg-deb --contents" dpkg-deb --contents "${debs}")
set(deb_files ./usr/lib/cmake/hapticloud/hapticloudConfig.cmake ./usr/include/hc/pipeline/run.hpp ./usr/bin/hapticloud
              ./usr/share/hapticloud/configs/sinusoid.yaml)
if(DEFINED PYTHON AND NOT PYTHON STREQUAL "")
  list(APPEND deb_files ./usr/lib/python3/dist-packages/hapticloud/__init__.py)
endif()
foreach(f ${deb_files})
  string(FIND "${step_output}" "${f}\n" at)
  if(at EQUAL -1)
    message(FATAL_ERROR "install test: ${debs} does not hold ${f}:\n${step_output}")
  endif()
endforeach()
if(NOT step_output MATCHES "\\./usr/lib/[^\n]*libhc_pipeline\\.a\n")
  message(FATAL_ERROR "install test: ${debs} does not hold libhc_pipeline.a:\n${step_output}")
endif()
step("dpkg-deb --field" dpkg-deb --field "${debs}" Package Version Depends)
if(NOT step_output MATCHES "Package: hapticloud\n" OR NOT step_output MATCHES "Version: ${VERSION}\n"
   OR NOT step_output MATCHES "libpcl-dev")
  message(FATAL_ERROR "install test: unexpected control fields of ${debs}:\n${step_output}")
endif()
