# Raspberry Pi 4, RK3399 big cores.
set(OCTOFUSE_CPU_FLAGS "-mcpu=cortex-a72")
