# Raspberry Pi 3 running a 32-bit OS: ARMv8 core in AArch32 state.
set(OCTOFUSE_CPU_FLAGS "-mcpu=cortex-a53 -mfpu=neon-fp-armv8 -mfloat-abi=hard")
