#!/usr/bin/env bash
# Instruction profile of the flight core on the emulated Cortex-M4 (few frames: `--features trace`).
# Usage: mcu-bench/scripts/profile.sh [N]. Needs qemu-system-arm, llvm-addr2line, python3.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --features trace
elf=target/thumbv7em-none-eabihf/release/mcu-bench
log=target/trace.log
qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native -icount shift=3 \
  -kernel "$elf" -d in_asm,exec,nochain -D "$log"
python3 scripts/profile.py "$log" "$elf" "${1:-20}"
