# Compile rules shared by every octofuse target.
#
# The warnings list is pinned (not -Weverything, not whatever a compiler adds later) so a compiler
# upgrade does not break the build by itself.
set(OCTOFUSE_WARNINGS
    -Wall -Wextra -Wpedantic -Wshadow -Wnon-virtual-dtor -Woverloaded-virtual -Wcast-align
    -Wformat=2 -Wimplicit-fallthrough -Wmissing-declarations -Wundef -Wvla)
if(OCTOFUSE_WERROR)
  list(APPEND OCTOFUSE_WARNINGS -Werror)
  # GCC 12 reports false "may be used uninitialized" inside Eigen's NEON packet code at -O3
  # (aarch64 Release); keep it visible as a warning, not a build stop.
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    list(APPEND OCTOFUSE_WARNINGS -Wno-error=maybe-uninitialized)
  endif()
endif()

# Bit-identical results across x86 and ARM need the same rounding: no FMA contraction, no fast-math.
# -fno-math-errno and -fno-trapping-math change no result (IEEE operations round the same; only
# errno and floating-point exception flags go unobserved); they let the compiler inline sqrt and
# vectorise loops with masked lanes, lane by lane the same operations as the scalar code. armv7
# NEON is not IEEE (it flushes denormals), so GCC keeps float code scalar there.
# lib/CMakeLists.txt hands them on (PUBLIC) with EIGEN_DONT_VECTORIZE, so every target that links
# the library gets them too; the helpers below also give them to targets that do not link it.
set(OCTOFUSE_FP_FLAGS -ffp-contract=off -fno-fast-math -fno-math-errno
                      -fno-trapping-math)

if(OCTOFUSE_SANITIZE)
  # No vptr check: lib/ and ports/ have no RTTI, so tests calling their virtual functions would
  # need typeinfo that is never emitted (undefined references at link time).
  add_compile_options(-fsanitize=address,undefined -fno-sanitize=vptr -fno-omit-frame-pointer
                      -fno-sanitize-recover=undefined)
  add_link_options(-fsanitize=address,undefined)
endif()

# ThreadSanitizer (the tsan preset, for the queries-while-mapping test). Not with ASan.
if(OCTOFUSE_SANITIZE_THREAD)
  if(OCTOFUSE_SANITIZE)
    message(FATAL_ERROR "OCTOFUSE_SANITIZE_THREAD and OCTOFUSE_SANITIZE exclude each other")
  endif()
  add_compile_options(-fsanitize=thread -fno-omit-frame-pointer)
  add_link_options(-fsanitize=thread)
endif()

# libFuzzer: coverage instrumentation everywhere; the fuzz targets link -fsanitize=fuzzer themselves.
if(OCTOFUSE_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
    message(FATAL_ERROR "OCTOFUSE_FUZZ=ON needs clang (use the fuzz preset)")
  endif()
  add_compile_options(-fsanitize=fuzzer-no-link)
endif()

# Eigen makes rebuilds slow; reuse objects across build folders when ccache is there.
option(OCTOFUSE_CCACHE "Compile through ccache when it is installed" ON)
if(OCTOFUSE_CCACHE AND NOT CMAKE_CXX_COMPILER_LAUNCHER)
  find_program(OCTOFUSE_CCACHE_PROGRAM ccache)
  if(OCTOFUSE_CCACHE_PROGRAM)
    set(CMAKE_C_COMPILER_LAUNCHER ${OCTOFUSE_CCACHE_PROGRAM})
    set(CMAKE_CXX_COMPILER_LAUNCHER ${OCTOFUSE_CCACHE_PROGRAM})
  endif()
endif()

# lib/ and ports/: the firmware rules (no exceptions, no RTTI).
function(octofuse_strict_target target)
  target_compile_options(${target} PRIVATE ${OCTOFUSE_WARNINGS} ${OCTOFUSE_FP_FLAGS}
                                           -fno-exceptions -fno-rtti)
endfunction()

# Tests and examples: same warnings, exceptions allowed (Catch2 needs them).
function(octofuse_host_target target)
  target_compile_options(${target} PRIVATE ${OCTOFUSE_WARNINGS} ${OCTOFUSE_FP_FLAGS})
endfunction()
