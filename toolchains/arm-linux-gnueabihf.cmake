# Cross-compiles octofuse for 32-bit ARM Linux boards with hard float (Raspberry Pi 2/3 running a
# 32-bit OS, BeagleBone, i.MX6, ...) with Debian's g++-arm-linux-gnueabihf. NEON is on by default
# (toolchains/cpu/armv7-neon.cmake); tests run on the build machine through qemu-user.
#
#   cmake --preset armhf                         (or -DCMAKE_TOOLCHAIN_FILE=toolchains/arm-linux-gnueabihf.cmake)
#   -DOCTOFUSE_CPU=cortex-a7                     picks toolchains/cpu/cortex-a7.cmake
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR armv7l)

set(OCTOFUSE_CROSS_TRIPLE arm-linux-gnueabihf)
set(OCTOFUSE_CPU_DEFAULT armv7-neon)
set(OCTOFUSE_QEMU qemu-arm)

include(${CMAKE_CURRENT_LIST_DIR}/cross-common.cmake)
