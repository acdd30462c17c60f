# Raspberry Pi 2, i.MX7, Allwinner H3: NEON with VFPv4.
set(OCTOFUSE_CPU_FLAGS "-mcpu=cortex-a7 -mfpu=neon-vfpv4 -mfloat-abi=hard")
