# Warnings for project targets only (third-party headers come in as SYSTEM).
function(hc_set_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow -Wconversion
    -Wno-sign-conversion -Wnon-virtual-dtor -Wold-style-cast -Woverloaded-virtual)
  # In a unity build a file's anonymous-namespace types are no longer in the main file, and GCC
  # warns about every class that uses one (-Wsubobject-linkage); within one target they are
  # still private to it.
  if(HC_UNITY_BUILD AND CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    target_compile_options(${target} PRIVATE -Wno-subobject-linkage)
  endif()
  if(HC_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
endfunction()
