# Shared part of the Debian cross toolchain files. The including file sets
# OCTOFUSE_CROSS_TRIPLE, OCTOFUSE_CPU_DEFAULT and OCTOFUSE_QEMU.

set(CMAKE_C_COMPILER ${OCTOFUSE_CROSS_TRIPLE}-gcc)
set(CMAKE_CXX_COMPILER ${OCTOFUSE_CROSS_TRIPLE}-g++)

# Debian's multiarch-free cross layout: headers and libraries of the target live in /usr/<triple>.
set(CMAKE_FIND_ROOT_PATH /usr/${OCTOFUSE_CROSS_TRIPLE})
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
# Packages: BOTH, so the header-only Eigen3 package config in /usr/share/eigen3 is still found.
# Packages with target binaries (libpng, OpenNI2, libcamera) are not installed for the target,
# their find_* calls fail in the target root and the ports that need them turn off under AUTO.
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)
# pkg-config must not report the host's x86 libraries.
set(ENV{PKG_CONFIG_LIBDIR} /usr/lib/${OCTOFUSE_CROSS_TRIPLE}/pkgconfig:/usr/${OCTOFUSE_CROSS_TRIPLE}/lib/pkgconfig)
set(ENV{PKG_CONFIG_SYSROOT_DIR} "")

# Tests (ctest, add_test, try_run) run through qemu-user with the target's loader and libraries.
find_program(OCTOFUSE_QEMU_PROGRAM ${OCTOFUSE_QEMU})
if(OCTOFUSE_QEMU_PROGRAM)
  set(CMAKE_CROSSCOMPILING_EMULATOR ${OCTOFUSE_QEMU_PROGRAM};-L;/usr/${OCTOFUSE_CROSS_TRIPLE})
endif()

# CPU flags live in toolchains/cpu/<name>.cmake so a board picks its own: -DOCTOFUSE_CPU=<name>.
set(OCTOFUSE_CPU ${OCTOFUSE_CPU_DEFAULT} CACHE STRING
    "CPU flag file from toolchains/cpu/ (without .cmake)")
if(NOT EXISTS ${CMAKE_CURRENT_LIST_DIR}/cpu/${OCTOFUSE_CPU}.cmake)
  message(FATAL_ERROR "OCTOFUSE_CPU=${OCTOFUSE_CPU}: no toolchains/cpu/${OCTOFUSE_CPU}.cmake")
endif()
include(${CMAKE_CURRENT_LIST_DIR}/cpu/${OCTOFUSE_CPU}.cmake)
# try_compile projects read this file again: hand them the same CPU choice.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES OCTOFUSE_CPU)
# The toolchain file is read several times (once per try_compile): set the flags, do not append.
set(CMAKE_C_FLAGS_INIT "${OCTOFUSE_CPU_FLAGS}")
set(CMAKE_CXX_FLAGS_INIT "${OCTOFUSE_CPU_FLAGS}")
