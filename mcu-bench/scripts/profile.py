#!/usr/bin/env python3
"""Where the emulated Cortex-M4 spends its instructions: reads a QEMU log of `-d in_asm,exec,nochain` (every
translated block once, every execution of one), weighs each block by its instruction count and prints the top
functions and source lines (`llvm-addr2line` on the ELF). Usage: profile.py TRACE.log ELF [N]."""
import collections
import re
import subprocess
import sys

log, elf = sys.argv[1], sys.argv[2]
top = int(sys.argv[3]) if len(sys.argv) > 3 else 20
length, function, runs = {}, {}, collections.Counter()
start, name = None, "?"
with open(log, errors="replace") as f:
    for line in f:
        if line.startswith("IN:"):
            start, name = None, line[3:].strip()
        elif m := re.match(r"0x([0-9a-f]+):\s", line):
            pc = int(m.group(1), 16)
            start = pc if start is None else start
            length[start] = length.get(start, 0) + 1
            function[start] = name
        elif line.startswith("Trace") and (m := re.search(r"\[[0-9a-f]+/([0-9a-f]+)/", line)):
            runs[int(m.group(1), 16)] += 1
weight = {pc: n * length.get(pc, 0) for pc, n in runs.items()}
total = sum(weight.values())
by_function = collections.Counter()
for pc, w in weight.items():
    by_function[function.get(pc, "?")] += w
print(f"{total} instructions executed")
for f, w in by_function.most_common(top):
    print(f"{w:>12} {100 * w / total:5.1f} %  {f[:100]}")
hot = [pc for pc, _ in sorted(weight.items(), key=lambda kv: -kv[1])[:top]]
where = subprocess.run(["llvm-addr2line", "-e", elf] + [hex(pc) for pc in hot], capture_output=True,
                       text=True).stdout
print("\nhottest blocks (source line of their first instruction):")
lines = iter(where.splitlines())
for pc in hot:
    loc = next(lines, "?")
    print(f"{weight[pc]:>12} {100 * weight[pc] / total:5.1f} %  {hex(pc)}  {length[pc]:>4} instr  {loc}")
