# Cross-compiles octofuse for 64-bit ARM Linux boards (Raspberry Pi 4/5, Jetson, RK3588, ...)
# with Debian's g++-aarch64-linux-gnu. Tests run on the build machine through qemu-user.
#
#   cmake --preset aarch64                       (or -DCMAKE_TOOLCHAIN_FILE=toolchains/aarch64-linux-gnu.cmake)
#   -DOCTOFUSE_CPU=cortex-a72                    picks toolchains/cpu/cortex-a72.cmake
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)

set(OCTOFUSE_CROSS_TRIPLE aarch64-linux-gnu)
set(OCTOFUSE_CPU_DEFAULT armv8-a)
set(OCTOFUSE_QEMU qemu-aarch64)

include(${CMAKE_CURRENT_LIST_DIR}/cross-common.cmake)
