# Raspberry Pi 5, RK3588 big cores.
set(OCTOFUSE_CPU_FLAGS "-mcpu=cortex-a76")
