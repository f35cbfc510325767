#!/usr/bin/env python3
"""Memory budgets of the firmware ELF: flash, SRAM and CCM RAM, from its program headers and sections.

Usage:
    python3 tools/fw-check/size.py target/thumbv7em-none-eabihf/fw/firmware \
        [--flash-max BYTES] [--sram-max BYTES] [--ccm-max BYTES] [--json out.json]

What is counted (every allocated section, by where it lives):
- flash: the bytes the image occupies in flash, i.e. the file size of every PT_LOAD segment whose physical (load)
  address is in flash (0x0800_0000..0x0810_0000): the vector table, .text, .rodata and the image of .data;
- SRAM: the memory size of every allocated section whose address (VMA) is in SRAM1+SRAM2 (0x2000_0000..0x2002_0000):
  .data, .bss, .uninit (the stack is the rest of the region, checked by stack.py);
- CCM: the same for 0x1000_0000..0x1001_0000 (.ccmram, NOLOAD).

Exit status: 0 when every figure is within its budget, 1 when one is over (the reasons are printed last), 2 on a
usage or file error. Needs pyelftools.
"""

import argparse
import json
import sys

from elftools.elf.elffile import ELFFile
from elftools.common.exceptions import ELFError

FLASH = (0x0800_0000, 0x0810_0000)
SRAM = (0x2000_0000, 0x2002_0000)
CCM = (0x1000_0000, 0x1001_0000)


def within(addr, region):
    return region[0] <= addr < region[1]


def measure(elf):
    """Bytes in flash, SRAM and CCM, and the sections behind each figure."""
    flash = sum(
        seg["p_filesz"]
        for seg in elf.iter_segments()
        if seg["p_type"] == "PT_LOAD" and seg["p_filesz"] > 0 and within(seg["p_paddr"], FLASH)
    )
    sections = {"sram": {}, "ccm": {}}
    for sec in elf.iter_sections():
        if not sec["sh_flags"] & 0x2 or sec["sh_size"] == 0:  # SHF_ALLOC
            continue
        for name, region in (("sram", SRAM), ("ccm", CCM)):
            if within(sec["sh_addr"], region):
                sections[name][sec.name] = sec["sh_size"]
    flash_sections = {
        sec.name: sec["sh_size"]
        for sec in elf.iter_sections()
        if sec["sh_flags"] & 0x2 and sec["sh_size"] > 0 and sec["sh_type"] != "SHT_NOBITS"
        and (within(sec["sh_addr"], FLASH) or within(sec["sh_addr"], SRAM))
    }
    return {
        "flash": {"bytes": flash, "sections": flash_sections},
        "sram": {"bytes": sum(sections["sram"].values()), "sections": sections["sram"]},
        "ccm": {"bytes": sum(sections["ccm"].values()), "sections": sections["ccm"]},
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("elf")
    ap.add_argument("--flash-max", type=int, default=None, help="flash budget, bytes")
    ap.add_argument("--sram-max", type=int, default=None, help="SRAM budget (data + bss + uninit), bytes")
    ap.add_argument("--ccm-max", type=int, default=None, help="CCM RAM budget, bytes")
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args(argv)
    try:
        with open(args.elf, "rb") as f:
            figures = measure(ELFFile(f))
    except (OSError, ELFError) as e:
        print(f"size.py: {args.elf}: {e}", file=sys.stderr)
        return 2
    budgets = {"flash": args.flash_max, "sram": args.sram_max, "ccm": args.ccm_max}
    failures = []
    print(f"{'memory':<8}{'bytes':>10}{'budget':>10}{'used':>8}  sections")
    for name, fig in figures.items():
        budget = budgets[name]
        fig["budget"] = budget
        used = f"{100 * fig['bytes'] / budget:.1f} %" if budget else "-"
        parts = " + ".join(f"{k} {v}" for k, v in fig["sections"].items())
        print(f"{name:<8}{fig['bytes']:>10}{budget if budget else '-':>10}{used:>8}  {parts}")
        if budget is not None and fig["bytes"] > budget:
            failures.append(f"{name}: {fig['bytes']} B, over the {budget} B budget by {fig['bytes'] - budget} B")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=1)
    if failures:
        print("FAIL:")
        for reason in failures:
            print(f"  - {reason}")
        return 1
    print("RESULT: PASS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
