#!/usr/bin/env python3
"""Memory budgets of a firmware ELF (the application or the bootloader): flash, SRAM and CCM RAM, from its program
headers and sections, and the regions each must stay inside.

Usage:
    python3 tools/fw-check/size.py target/thumbv7em-none-eabihf/fw/firmware \
        [--flash-max BYTES] [--sram-max BYTES] [--ccm-max BYTES] \
        [--flash-region START:END] [--sram-region START:END] [--json out.json]

Regions (`docs/update.md`, `firmware/src/layout.rs`): with --flash-region every flash PT_LOAD segment (its load
address and file size) must lie inside [START, END) — the application's is ACTIVE after the image header, the
bootloader's its two sectors; with --sram-region every allocated SRAM section must — neither may touch the boot
report at the start of SRAM. START and END are numbers as Python reads them (0x0802_0200, 131072).

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


def outside(elf, flash_region=None, sram_region=None):
    """What lies outside the given regions: a list of reasons (empty when everything is inside)."""
    reasons = []
    if flash_region:
        lo, hi = flash_region
        for seg in elf.iter_segments():
            if seg["p_type"] != "PT_LOAD" or seg["p_filesz"] == 0 or not within(seg["p_paddr"], FLASH):
                continue
            start, end = seg["p_paddr"], seg["p_paddr"] + seg["p_filesz"]
            if start < lo or end > hi:
                reasons.append(f"flash: a segment at 0x{start:08x}..0x{end:08x} is outside 0x{lo:08x}..0x{hi:08x}")
    if sram_region:
        lo, hi = sram_region
        for sec in elf.iter_sections():
            if not sec["sh_flags"] & 0x2 or sec["sh_size"] == 0 or not within(sec["sh_addr"], SRAM):
                continue
            start, end = sec["sh_addr"], sec["sh_addr"] + sec["sh_size"]
            if start < lo or end > hi:
                reasons.append(f"sram: {sec.name} at 0x{start:08x}..0x{end:08x} is outside 0x{lo:08x}..0x{hi:08x}")
    return reasons


def region(text):
    """START:END as a (start, end) pair."""
    try:
        lo, hi = (int(x, 0) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not START:END")
    if lo >= hi:
        raise argparse.ArgumentTypeError(f"{text!r}: START must be below END")
    return lo, hi


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
    ap.add_argument("--flash-region", type=region, default=None, metavar="START:END",
                    help="every flash segment inside [START, END)")
    ap.add_argument("--sram-region", type=region, default=None, metavar="START:END",
                    help="every SRAM section inside [START, END)")
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args(argv)
    try:
        with open(args.elf, "rb") as f:
            elf = ELFFile(f)
            figures = measure(elf)
            failures = outside(elf, args.flash_region, args.sram_region)
    except (OSError, ELFError) as e:
        print(f"size.py: {args.elf}: {e}", file=sys.stderr)
        return 2
    budgets = {"flash": args.flash_max, "sram": args.sram_max, "ccm": args.ccm_max}
    for name, reg in (("flash", args.flash_region), ("sram", args.sram_region)):
        if reg:
            figures[name]["region"] = list(reg)
            print(f"{name} region 0x{reg[0]:08x}..0x{reg[1]:08x}: {'inside' if not any(r.startswith(name) for r in failures) else 'NOT inside'}")
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
