# Generic 32-bit ARMv7-A with hard float and NEON (VFPv3-D32 + Advanced SIMD).
set(OCTOFUSE_CPU_FLAGS "-march=armv7-a -mfpu=neon -mfloat-abi=hard")
