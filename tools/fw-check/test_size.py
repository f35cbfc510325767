"""Unit tests of size.py on a small ELF32 written here (no toolchain needed).

Run with ``python3 -m pytest tools/fw-check``. The ELF mimics the firmware's layout: .text in flash, .data in SRAM
loaded from flash (its image counts in flash and in SRAM), .bss in SRAM (SRAM only), .ccmram NOLOAD in CCM (CCM
only); the expected figures are sums of the sizes chosen below.
"""

import os
import struct
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import size  # noqa: E402

SHF_WRITE, SHF_ALLOC, SHF_EXEC = 1, 2, 4
PROGBITS, NOBITS, STRTAB = 1, 8, 3

# (name, type, flags, vma, size); .data is loaded from flash at 0x0800_2000.
SECTIONS = [
    (".text", PROGBITS, SHF_ALLOC | SHF_EXEC, 0x0800_0000, 0x1000),
    (".data", PROGBITS, SHF_ALLOC | SHF_WRITE, 0x2000_0000, 0x300),
    (".bss", NOBITS, SHF_ALLOC | SHF_WRITE, 0x2000_0300, 0x500),
    (".ccmram", NOBITS, SHF_ALLOC | SHF_WRITE, 0x1000_0000, 0x800),
    (".comment", PROGBITS, 0, 0, 0x10),
]
DATA_LMA = 0x0800_2000


def write_elf(path):
    shstr = b"\0" + b"".join(n.encode() + b"\0" for n, *_ in SECTIONS) + b".shstrtab\0"
    name_off = {}
    off = 1
    for n, *_ in SECTIONS:
        name_off[n] = off
        off += len(n) + 1
    shstr_name = off
    ehsize, phentsize, shentsize = 52, 32, 40
    phnum = 4
    body_off = ehsize + phnum * phentsize
    payload, offsets = b"", {}
    for n, typ, _, _, sz in SECTIONS:
        offsets[n] = body_off + len(payload)
        if typ != NOBITS:
            payload += b"\xaa" * sz
    shstr_off = body_off + len(payload)
    payload += shstr
    shoff = body_off + len(payload)
    header = b"\x7fELF" + bytes([1, 1, 1, 0]) + bytes(8)
    header += struct.pack("<HHIIIIIHHHHHH", 2, 40, 1, 0x0800_0000, ehsize, shoff, 0x0500_0400, ehsize, phentsize,
                          phnum, shentsize, len(SECTIONS) + 2, len(SECTIONS) + 1)
    sec = dict((n, (t, f, a, s)) for n, t, f, a, s in SECTIONS)
    phdrs = b"".join([
        # PT_LOAD: type, offset, vaddr, paddr, filesz, memsz, flags, align
        struct.pack("<IIIIIIII", 1, offsets[".text"], 0x0800_0000, 0x0800_0000, 0x1000, 0x1000, 5, 4),
        struct.pack("<IIIIIIII", 1, offsets[".data"], 0x2000_0000, DATA_LMA, 0x300, 0x300, 6, 4),
        struct.pack("<IIIIIIII", 1, offsets[".data"], 0x2000_0300, 0x2000_0300, 0, 0x500, 6, 4),
        struct.pack("<IIIIIIII", 1, offsets[".data"], 0x1000_0000, 0x1000_0000, 0, 0x800, 6, 4),
    ])
    shdrs = bytes(shentsize)
    for n, (t, f, a, s) in sec.items():
        shdrs += struct.pack("<IIIIIIIIII", name_off[n], t, f, a, offsets[n], s, 0, 0, 4, 0)
    shdrs += struct.pack("<IIIIIIIIII", shstr_name, STRTAB, 0, 0, shstr_off, len(shstr), 0, 0, 1, 0)
    with open(path, "wb") as f:
        f.write(header + phdrs + payload + shdrs)


def test_figures_by_region(tmp_path):
    elf = tmp_path / "fw.elf"
    write_elf(elf)
    with open(elf, "rb") as f:
        figs = size.measure(size.ELFFile(f))
    assert figs["flash"]["bytes"] == 0x1000 + 0x300  # .text + .data's image; .bss/.ccmram take no flash
    assert figs["sram"]["bytes"] == 0x300 + 0x500
    assert figs["ccm"]["bytes"] == 0x800


def test_budgets_pass_and_fail(tmp_path, capsys):
    elf = tmp_path / "fw.elf"
    write_elf(elf)
    assert size.main([str(elf), "--flash-max", str(0x1300), "--sram-max", str(0x800), "--ccm-max", str(0x800)]) == 0
    assert size.main([str(elf), "--flash-max", str(0x12FF)]) == 1
    assert "over the 4863 B budget by 1 B" in capsys.readouterr().out
    assert size.main([str(tmp_path / "missing")]) == 2


def test_regions(tmp_path, capsys):
    """.text at 0x0800_0000, .data's image at 0x0800_2000..0x0800_2300; .data and .bss at 0x2000_0000..0x2000_0800."""
    elf = tmp_path / "fw.elf"
    write_elf(elf)
    assert size.main([str(elf), "--flash-region", "0x0800_0000:0x0800_2300", "--sram-region", "0x2000_0000:0x2000_0800"]) == 0
    # the application's region (ACTIVE after its header) does not hold this ELF's flash
    assert size.main([str(elf), "--flash-region", "0x0802_0200:0x0806_0000"]) == 1
    assert "flash: a segment at 0x08000000..0x08001000 is outside 0x08020200..0x08060000" in capsys.readouterr().out
    # one byte short at the end
    assert size.main([str(elf), "--flash-region", "0x0800_0000:0x0800_22ff"]) == 1
    # the boot report's 32 bytes at the start of SRAM must stay free
    assert size.main([str(elf), "--sram-region", "0x2000_0020:0x2002_0000"]) == 1
    assert "sram: .data at 0x20000000..0x20000300 is outside 0x20000020..0x20020000" in capsys.readouterr().out
