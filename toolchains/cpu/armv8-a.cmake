# Generic 64-bit ARMv8-A: runs on every aarch64 board (Advanced SIMD is part of the base ISA).
set(OCTOFUSE_CPU_FLAGS "-march=armv8-a")
