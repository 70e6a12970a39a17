# Toolchain: a 32-bit RISC-V core like the ESP32-C3/C6's, with Debian's bare-metal
# GCC (gcc-riscv64-unknown-elf) and C library (picolibc-riscv64-unknown-elf).
set(CMAKE_SYSTEM_NAME Generic)
set(CMAKE_SYSTEM_PROCESSOR riscv32)
set(CMAKE_C_COMPILER riscv64-unknown-elf-gcc)
set(CMAKE_C_FLAGS_INIT "--specs=picolibc.specs -march=rv32imc_zicsr -mabi=ilp32 -Os")
set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY) # no OS to link a test program against
