#!/usr/bin/env python3
"""Tests of the flash model (boot.FlashIf, boot.Machine's program/erase, fastblock's C paths) and of the loader of
several ELFs and raw images (boot.ImageSet, VTOR): the register semantics on their own, then tiny hand-assembled
Thumb-2 firmwares (llvm-mc + rust-lld, as test_boot.py; skipped when those are missing) that unlock, erase, program,
make every kind of mistake, jump from a "bootloader" to an "application", and swap one in; last the real firmware's
calibration store (skipped when its ELF is missing).

    python3 -m pytest -q tools/fw-check/test_flash.py
"""

import contextlib
import os
import shutil
import struct
import sys
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import boot  # noqa: E402
import emu  # noqa: E402
import fastblock  # noqa: E402
from test_boot import POLL, FakeMachine, args, assemble, find_lld, thumb_func  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
FW_ELF = os.environ.get("FW_ELF", os.path.join(ROOT, "target/thumbv7em-none-eabihf/fw/firmware"))
RES = 0x2000_4000  # where the test firmwares write what they saw (SRAM, kept across resets)
F = boot.FlashIf
FLASH_IF = 0x4002_3C00
HAVE_TOOLS = bool(shutil.which("llvm-mc") and find_lld() and shutil.which("llvm-objdump"))


class FakeFlashMachine(FakeMachine):
    """Enough of boot.Machine for FlashIf alone: erases and programs are recorded, not done."""

    def __init__(self):
        super().__init__()
        self.flash_bsy_polls = 2
        self.flash_log = {"unlocks": 0}
        self.violations, self.erases, self.stops = [], [], []

    def flash_violation(self, text):
        self.violations.append(text)

    def flash_erase(self, sectors, psize, mass):
        self.erases.append((sectors, psize, mass))

    def flash_program(self, off, size, value, old):
        return old & value

    def stop(self, kind, msg):
        self.stops.append(kind)


class RegisterTests(unittest.TestCase):
    def setUp(self):
        self.m = FakeFlashMachine()
        self.f = F(self.m, "FLASH", FLASH_IF)

    def unlock(self):
        self.f.write(F.KEYR, 4, F.KEY1)
        self.f.write(F.KEYR, 4, F.KEY2)

    def test_reset_values_and_unlock(self):
        f = self.f
        self.assertEqual(f.read(F.CR, 4), 0x8000_0000)
        self.assertEqual(f.read(F.OPTCR, 4), 0x0FFF_AAED)
        f.write(F.CR, 4, F.PG)  # locked: ignored, reported
        self.assertEqual(f.read(F.CR, 4), 0x8000_0000)
        self.assertEqual(len(self.m.violations), 1)
        self.unlock()
        self.assertEqual(f.read(F.CR, 4), 0)
        self.assertEqual(self.m.flash_log["unlocks"], 1)
        f.write(F.CR, 4, F.PG | (2 << 8))
        self.assertEqual(f.read(F.CR, 4), F.PG | (2 << 8))
        f.write(F.CR, 4, 0)  # LOCK is write-1-only: a 0 does not lock, a 1 does
        self.assertEqual(f.read(F.CR, 4), 0)
        f.write(F.CR, 4, F.LOCK)
        self.assertEqual(f.read(F.CR, 4), F.LOCK)

    def test_wrong_key_locks_until_reset_with_a_bus_error(self):
        f = self.f
        f.write(F.KEYR, 4, F.KEY1)
        f.write(F.KEYR, 4, 0x1234_5678)
        self.assertEqual(self.m.stops, ["fault"])
        self.unlock()  # the right sequence no longer unlocks
        self.assertEqual(f.read(F.CR, 4), 0x8000_0000)

    def test_sr_write_one_to_clear_and_bsy_polls(self):
        f = self.f
        self.unlock()
        f.write(F.CR, 4, F.SER | (5 << 3) | (2 << 8) | F.EOPIE)
        f.write(F.CR + 2, 1, 1)  # STRT by a byte write (bit 16): the operation starts
        self.assertEqual(self.m.erases, [([5], 2, False)])
        self.assertEqual([f.read(F.SR, 4) for _ in range(3)], [F.BSY | F.EOP, F.BSY | F.EOP, F.EOP])
        self.assertEqual(f.read(F.CR, 4) & F.STRT, 0)  # STRT reads back 0
        f.write(F.SR, 4, F.PGSERR)  # not set: nothing changes
        self.assertEqual(f.read(F.SR, 4), F.EOP)
        f.write(F.SR, 4, F.EOP)
        self.assertEqual(f.read(F.SR, 4), 0)

    def test_program_errors(self):
        f = self.f
        self.assertEqual(f.program(0x2_0000, 4, 0, 0xFFFF_FFFF), 0xFFFF_FFFF)  # locked
        self.assertEqual(f.read(F.SR, 4), F.PGSERR)
        self.unlock()
        f.write(F.SR, 4, 0xF3)
        self.assertEqual(f.program(0x2_0000, 4, 0, 0xFFFF_FFFF), 0xFFFF_FFFF)  # PG not set
        self.assertEqual(f.read(F.SR, 4), F.PGSERR)
        f.write(F.SR, 4, 0xF3)
        f.write(F.CR, 4, F.PG | (2 << 8) | F.ERRIE)  # x32
        self.assertEqual(f.program(0x2_0000, 1, 0, 0xFF), 0xFF)  # a byte at x32
        self.assertEqual(f.read(F.SR, 4), F.PGPERR | F.OPERR)
        f.write(F.SR, 4, 0xF3)
        self.assertEqual(f.program(0x2_000E, 4, 0, 0xFFFF_FFFF), 0xFFFF_FFFF)  # crosses a 128-bit row
        self.assertEqual(f.read(F.SR, 4), F.PGAERR | F.OPERR)
        f.write(F.SR, 4, 0xF3)
        self.assertEqual(f.program(0x2_0004, 4, 0x0F0F_0F0F, 0xFF00_FF00), 0x0F00_0F00)  # AND
        self.assertEqual(f.read(F.SR, 4) & ~F.BSY, 0)
        self.assertEqual(len(self.m.violations), 4)

    def test_strt_without_ser_and_bad_snb(self):
        f = self.f
        self.unlock()
        f.write(F.CR, 4, F.STRT)
        self.assertEqual(self.m.erases, [])
        f.write(F.CR, 4, F.SER | (12 << 3) | F.STRT)
        self.assertEqual(self.m.erases, [])
        self.assertTrue(f.read(F.SR, 4) & F.WRPERR)
        self.assertEqual(len(self.m.violations), 2)

    def test_sector_table(self):
        self.assertEqual(boot.flash_sector_of(0x0800_3FFF), (0, 0x0800_0000, 16 << 10))
        self.assertEqual(boot.flash_sector_of(0x0801_0000), (4, 0x0801_0000, 64 << 10))
        self.assertEqual(boot.flash_sector_of(0x0802_0200), (5, 0x0802_0000, 128 << 10))
        self.assertEqual(boot.flash_sector_of(0x080F_FFFF), (11, 0x080E_0000, 128 << 10))
        self.assertIsNone(boot.flash_sector_of(0x0810_0000))
        self.assertEqual(sum(s for _, s in boot.FLASH_SECTORS), boot.FLASH_SIZE)


def ld_script(origin: int) -> str:
    return f"""MEMORY {{ FLASH (rx) : ORIGIN = 0x{origin:08x}, LENGTH = 0x{0x0810_0000 - origin:x}
         RAM (rwx) : ORIGIN = 0x20000000, LENGTH = 128K }}
_stack_end = 0x20000000;
_stack_start = 0x20001000;
SECTIONS {{
  .vector_table ORIGIN(FLASH) : {{ KEEP(*(.vector_table)) }} > FLASH
  .text : {{ *(.text .text.*) }} > FLASH
}}
"""


def firmware(body: str, origin: int = boot.FLASH_BASE, extra: str = "", poll: int | None = None) -> str:
    """Assembly of a tiny firmware: a vector table (every exception to Hang), Reset = body."""
    polls = "" if poll is None else f"""
.thumb_func
.type {POLL.format(n=poll)},%function
{POLL.format(n=poll)}:
  bx lr
.size {POLL.format(n=poll)}, .-{POLL.format(n=poll)}
"""
    return f""".syntax unified
.cpu cortex-m4
.thumb
.section .vector_table,"a",%progbits
.word _stack_start
.word Reset
.rept 14
.word Hang
.endr
.text
.thumb_func
.global Hang
.type Hang,%function
Hang: b Hang
.size Hang, .-Hang
{thumb_func("Reset", body)}
{polls}
{extra}
.ltorg
"""


UNLOCK = """  ldr r0, =0x45670123
  str r0, [r4, #4]
  ldr r0, =0xCDEF89AB
  str r0, [r4, #4]
"""


def wait(label: str) -> str:
    return f"""{label}: ldr r1, [r4, #0xC]
  tst r1, #0x10000
  bne {label}b
"""


def start_erase(label: str = "9") -> str:
    """The sector erase whose CR value (SER, SNB, PSIZE) is in r0: CR, then STRT, then the wait until BSY clears."""
    return f"""  str r0, [r4, #0x10]
  orr r0, r0, #0x10000
  str r0, [r4, #0x10]
{wait(label)}"""


def erase(snb: int, psize: int, label: str = "9") -> str:
    return f"""  ldr r0, =(2 | ({snb} << 3) | ({psize} << 8))
{start_erase(label)}"""


def jump(vector_table: int) -> str:
    """What a bootloader ends with: VTOR to the application's vector table, its MSP, a branch to its Reset."""
    return f"""  ldr r0, =0xE000ED08
  ldr r1, ={vector_table}
  str r1, [r0]
  ldr r2, [r1]
  msr msp, r2
  ldr r3, [r1, #4]
  bx r3
"""


def record(off: int, at: int) -> str:
    """SR and then the word at r5 + off, to RES + at and RES + at + 4 (r4: the flash interface, r7: RES)."""
    return f"""  ldr r1, [r4, #0xC]
  str r1, [r7, #{at}]
  ldr r1, [r5, #{off}]
  str r1, [r7, #{at + 4}]
"""


IDLE = "99: wfe\n  b 99b\n"


@contextlib.contextmanager
def no_c():
    """fastblock's C paths off (the Python model and block hook)."""
    real = fastblock.library
    fastblock.library = lambda: None
    try:
        yield
    finally:
        fastblock.library = real


class FlashTestBase(unittest.TestCase):
    """Builds and runs the tiny firmwares (no tests of its own)."""

    def build(self, src: str, origin: int = boot.FLASH_BASE) -> str:
        return assemble(self, src, ld_script(origin), "flash-test-")

    def sim(self, img, **kw):
        m = emu.Sim(img, args(spin_limit=5000), **kw)
        m.power_on()
        return m

    @staticmethod
    def words(m, n, at=RES):
        return struct.unpack(f"<{n}I", bytes(m.uc.mem_read(at, 4 * n)))


@unittest.skipUnless(HAVE_TOOLS, "needs llvm-mc, rust-lld and llvm-objdump")
class SyntheticFlashTests(FlashTestBase):

    # the register sequence of embassy-stm32 0.6's F4 driver, and every mistake the model must catch
    SEQUENCE = f"""  ldr r7, ={RES}
  ldr r4, ={FLASH_IF}
  ldr r1, [r4, #0x10]
  str r1, [r7, #0]
{UNLOCK}  ldr r1, [r4, #0x10]
  str r1, [r7, #4]
  ldr r0, =(2 | (5 << 3) | (2 << 8))
  str r0, [r4, #0x10]
  orr r0, r0, #0x10000
  str r0, [r4, #0x10]
  movs r2, #0
1: ldr r1, [r4, #0xC]
  adds r2, #1
  tst r1, #0x10000
  bne 1b
  str r2, [r7, #8]
  str r1, [r7, #12]
  ldr r0, =(1 | (2 << 8) | (1 << 24))
  str r0, [r4, #0x10]
  ldr r5, =0x08020000
  ldr r0, =0x12345678
  str r0, [r5]
{wait("2")}  str r1, [r7, #16]
  movs r0, #1
  str r0, [r4, #0xC]
  ldr r1, [r4, #0xC]
  str r1, [r7, #20]
  ldr r0, =0xFFFF0000
  str r0, [r5, #4]
{wait("3")}  ldr r0, =0x0F0F0F0F
  str r0, [r5]
{wait("4")}  ldr r1, [r5]
  str r1, [r7, #24]
  ldr r0, =(1 | (2 << 8) | (1 << 25))
  str r0, [r4, #0x10]
  movs r0, #0
  strb r0, [r5, #8]
{record(8, 28)}  ldr r0, =0xF3
  str r0, [r4, #0xC]
  ldr r0, =0x80000000
  str r0, [r4, #0x10]
  movs r0, #0
  str r0, [r5, #12]
{record(12, 36)}  movs r0, #1
  str r0, [r4, #0x10]
  ldr r1, [r4, #0x10]
  str r1, [r7, #44]
  ldr r5, =0x00020010
  ldr r0, =0xF3
  str r0, [r4, #0xC]
{UNLOCK}  ldr r0, =(1 | (2 << 8))
  str r0, [r4, #0x10]
  ldr r0, =0xA5A5A5A5
  str r0, [r5]
{wait("5")}  ldr r5, =0x08020010
  ldr r1, [r5]
  str r1, [r7, #48]
{IDLE}"""

    WANT = [0x8000_0000, 0,  # CR at reset, unlocked
            2, 0,  # SR reads until BSY clears (bsy_polls + 1), SR after the erase (no EOPIE: no EOP)
            F.EOP, 0,  # EOP with EOPIE, cleared by writing 1
            0x0204_0608,  # 0x0F0F0F0F programmed over 0x12345678: AND
            F.PGPERR | F.OPERR | F.EOP, 0xFFFF_FFFF,  # a byte at x32 with ERRIE, not programmed (EOP: the
            # over-program's, EOPIE was on)
            F.PGSERR, 0xFFFF_FFFF,  # a store while locked, not programmed
            0x8000_0000,  # a CR write while locked, ignored
            0xA5A5_A5A5]  # programmed through the boot alias, read at 0x0802_0010

    def run_sequence(self, engine: str):
        path = self.build(firmware(self.SEQUENCE))
        img = boot.Image(path, need_stack=False)
        if engine == "machine":
            m = boot.Machine(img, args(spin_limit=5000))
            m.run(10.0, 5_000_000)
            self.assertEqual(m.stop_kind, "idle", m.stop_msg)
        else:
            ctx = no_c() if engine == "sim-python" else contextlib.nullcontext()
            with ctx:
                m = self.sim(img)
                r = m.run_until(5.0)
            self.assertEqual(r, "time", m.stop_msg)
            self.assertEqual(m.c_flash, engine == "sim-c")
        return m

    def test_embassy_sequence_and_violations_on_every_engine(self):
        results = {}
        engines = ("machine", "sim-python") + (("sim-c",) if fastblock.library() is not None else ())
        for engine in engines:
            with self.subTest(engine=engine):
                m = self.run_sequence(engine)
                got = list(self.words(m, len(self.WANT)))
                self.assertEqual(got, self.WANT, [hex(v) for v in got])
                s = m.flash_summary()
                self.assertEqual(s["erase_count"], 1)
                self.assertEqual(s["erases"][0]["sectors"], [5])
                self.assertEqual(s["erases"][0]["psize"], "x32")
                self.assertAlmostEqual(s["erase_s"], 2.0)  # 128 KiB at x32, DS8626 maximum
                self.assertEqual(s["programs"], 4)  # 2 words, the over-program, the alias word
                self.assertAlmostEqual(s["program_s"], 4 * 100e-6)
                self.assertEqual(s["overprograms"], 1)
                self.assertEqual(s["unlocks"], 2)
                # over-program, PGPERR, PGSERR (locked), CR written while locked
                self.assertEqual(s["violation_count"], 4, s["violations"])
                self.assertEqual(bytes(m.flash_mem[0x2_0000:0x2_0014]).hex(),
                                 "08060402" "0000ffff" "ffffffff" "ffffffff" "a5a5a5a5")
                self.assertTrue(all(b == 0xFF for b in m.flash_mem[0x2_0014:0x4_0000]))
                results[engine] = (got, bytes(m.flash_mem), {k: s[k] for k in ("programs", "program_s",
                                                                                 "erase_s", "violation_count")})
        self.assertEqual(results["machine"], results["sim-python"])
        if "sim-c" in results:
            self.assertEqual(results["sim-python"], results["sim-c"])

    def test_typical_timing_and_bsy_polls(self):
        path = self.build(firmware(self.SEQUENCE))
        m = self.sim(boot.Image(path), flash_timing="typ", flash_bsy_polls=3)
        m.run_until(5.0)
        self.assertEqual(self.words(m, 3)[2], 4)  # 3 BSY reads, then the 4th sees it clear
        s = m.flash_summary()
        self.assertAlmostEqual(s["erase_s"], 1.0)  # 128 KiB at x32, typical
        self.assertAlmostEqual(s["program_s"], 4 * 16e-6)

    def test_the_stall_is_seen_by_the_timers_and_x8_is_slower(self):
        # TIM2 at 1 MHz (HSI 16 MHz / 16) read before and after erasing sector 6 at x8 (PSIZE as embassy's
        # write path leaves it): 4 s at the maximum
        body = f"""  ldr r7, ={RES}
  ldr r4, ={FLASH_IF}
  ldr r6, =0x40000000
  movs r0, #15
  str r0, [r6, #0x28]
  movs r0, #1
  str r0, [r6, #0x14]
  str r0, [r6]
  ldr r1, [r6, #0x24]
  str r1, [r7]
{UNLOCK}{erase(6, 0)}  ldr r1, [r6, #0x24]
  str r1, [r7, #4]
{IDLE}"""
        m = self.sim(boot.Image(self.build(firmware(body))))
        m.run_until(6.0)
        before, after = self.words(m, 2)
        self.assertAlmostEqual((after - before) / 1e6, 4.0, delta=1e-3)
        self.assertEqual(m.flash_summary()["erases"][0]["psize"], "x8")

    def test_an_iwdg_reset_cuts_an_erase_short(self):
        # first boot: IWDG started (0.512 s at the reset prescaler and reload), then a 4 s erase: the watchdog
        # resets the chip during it; the second boot sees the marker in SRAM and idles without the watchdog
        body = f"""  ldr r7, ={RES}
  ldr r0, [r7, #0x40]
  ldr r1, =0xB007B007
  cmp r0, r1
  beq 2f
  str r1, [r7, #0x40]
  ldr r0, =0x40003000
  ldr r1, =0xCCCC
  str r1, [r0]
  ldr r4, ={FLASH_IF}
{UNLOCK}{erase(6, 0)}  movs r0, #1
  str r0, [r7, #0x44]
{IDLE}2: movs r0, #2
  str r0, [r7, #0x48]
98: wfe
  b 98b
"""
        path = self.build(firmware(body))
        m = self.sim(boot.Image(path), max_resets=2)
        m.uc.mem_write(RES + 0x40, bytes(12))
        m.run_until(3.0)
        self.assertEqual([b["cause"] for b in m.boots], ["power-on", "iwdg"])
        e = m.flash_summary()["erases"]
        self.assertEqual(len(e), 1)
        self.assertTrue(e[0]["cut"])
        self.assertAlmostEqual(e[0]["duration_s"], 4096 * 4 / 32_000, delta=1e-3)
        self.assertEqual(self.words(m, 3, RES + 0x40)[1:], (0, 2))  # never past the erase; the second boot ran
        sector6 = bytes(m.flash_mem[0x4_0000:0x6_0000])
        self.assertNotEqual(sector6, b"\xff" * len(sector6))  # an interrupted erase leaves undefined contents

    def test_mass_erase(self):
        body = f"""  ldr r4, ={FLASH_IF}
{UNLOCK}  ldr r0, =(4 | (2 << 8))
  str r0, [r4, #0x10]
  orr r0, r0, #0x10000
  str r0, [r4, #0x10]
1: b 1b
"""
        m = self.sim(boot.Image(self.build(firmware(body))))
        m.run_until(20.0)
        s = m.flash_summary()
        self.assertTrue(s["erases"][0]["mass"])
        self.assertAlmostEqual(s["erase_s"], 16.0)
        self.assertTrue(all(b == 0xFF for b in m.flash_mem))  # the code too: execution then falls off erased flash


@unittest.skipUnless(HAVE_TOOLS, "needs llvm-mc, rust-lld and llvm-objdump")
class LoaderTests(FlashTestBase):
    """A "bootloader" at 0x0800_0000 that swaps (copies) an image from DFU into ACTIVE when the boot state sector
    says so, then sets VTOR and MSP and branches to the application at ACTIVE + 0x200; two "applications"."""

    ACTIVE, DFU, STATE = 0x0802_0000, 0x0806_0000, 0x0801_0000
    COPY_WORDS = 256

    def bootloader(self) -> str:
        body = f"""  ldr r7, ={RES}
  ldr r4, ={FLASH_IF}
  ldr r0, ={self.STATE}
  ldr r0, [r0]
  ldr r1, =0xF0F0F0F0
  cmp r0, r1
  bne 8f
{UNLOCK}{erase(5, 2, "1")}  ldr r0, =(1 | (2 << 8))
  str r0, [r4, #0x10]
  ldr r5, ={self.DFU}
  ldr r6, ={self.ACTIVE}
  ldr r3, ={self.COPY_WORDS}
2: ldr r0, [r5], #4
  str r0, [r6], #4
{wait("3")}  subs r3, #1
  bne 2b
{erase(4, 2, "4")}  ldr r0, =0x80000000
  str r0, [r4, #0x10]
  ldr r0, [r7, #0x10]
  adds r0, #1
  str r0, [r7, #0x10]
8:
{jump(self.ACTIVE + 0x200)}"""
        return self.build(firmware(body))

    def app(self, marker: int, pad: int, request: bool = False) -> str:
        """An application: its marker and VTOR to RES + 0x20; with `request`, it then asks for a swap (programs the
        swap magic into the state sector) and resets (SYSRESETREQ), as an update's Commit does."""
        req = f"""  ldr r4, ={FLASH_IF}
{UNLOCK}  ldr r0, =(1 | (2 << 8))
  str r0, [r4, #0x10]
  ldr r5, ={self.STATE}
  ldr r0, =0xF0F0F0F0
  str r0, [r5]
{wait("5")}  ldr r0, =0x80000000
  str r0, [r4, #0x10]
  dsb
  ldr r0, =0xE000ED0C
  ldr r1, =0x05FA0004
  str r1, [r0]
98: b 98b
"""
        body = f"""  ldr r7, ={RES}
  movs r0, #{marker}
  str r0, [r7, #0x20]
  ldr r0, =0xE000ED08
  ldr r0, [r0]
  str r0, [r7, #0x24]
{"  nop" + chr(10) if pad else ""}{"  nop" + chr(10) if pad else ""}  bl {POLL.format(n=marker)}
{req if request else ""}  sev
{IDLE}"""
        return self.build(firmware(body, poll=marker), origin=self.ACTIVE + 0x200)

    def test_direct_boot_of_an_application_alone(self):
        img = boot.Image(self.app(1, 0))
        self.assertEqual(img.vector_table, self.ACTIVE + 0x200)
        m = self.sim(img)
        m.run_until(0.01)
        self.assertEqual(self.words(m, 2, RES + 0x20), (1, self.ACTIVE + 0x200))
        self.assertTrue(any(e["kind"] == "direct_boot" for e in m.events))
        self.assertTrue(all(m.polled[a] for a in img.task_polls))
        bm = boot.Machine(img, args(spin_limit=5000))  # boot.py's machine too
        bm.run(5.0, 1_000_000)
        self.assertEqual(bm.stop_kind, "idle", bm.stop_msg)

    def image_set(self, swap: bool, request: bool = False):
        bl, app1, app2 = (boot.Image(p, need_stack=False) for p in (self.bootloader(), self.app(1, 0, request),
                                                                     self.app(2, 1)))
        blobs = []
        if swap:  # app2's flash contents in DFU as they will sit in ACTIVE (behind a 512-byte "header")
            payload = bytearray(b"\xff" * (self.COPY_WORDS * 4))
            for a, d in app2.flash_segments():
                payload[a - self.ACTIVE:a - self.ACTIVE + len(d)] = d
            blobs = [(self.DFU, bytes(payload), "app2 image")]
            if not request:  # else app1 asks for the swap itself
                blobs.append((self.STATE, b"\xf0" * 4, "swap magic"))
        return boot.ImageSet([bl, app1], candidates=[app2], blobs=blobs), bl, app1, app2

    def test_bootloader_jumps_to_the_application(self):
        for engine in ("sim-c", "sim-python"):
            with self.subTest(engine=engine), (no_c() if engine == "sim-python" else contextlib.nullcontext()):
                imgs, bl, app1, app2 = self.image_set(swap=False)
                m = self.sim(imgs)
                m.run_until(0.01)
                self.assertEqual(self.words(m, 2, RES + 0x20), (1, self.ACTIVE + 0x200))
                self.assertEqual([im.sha256 for im in imgs.active], [bl.sha256, app1.sha256])
                self.assertIs(imgs.primary, app1)
                self.assertTrue(any(e["kind"] == "vtor" for e in m.events))
                self.assertEqual(m.flash_summary()["erase_count"], 0)
                poll1 = next(iter(app1.task_polls))
                self.assertEqual(m.polled[poll1], 1)

    def test_bootloader_swaps_and_the_emulator_follows(self):
        for engine in ("sim-c", "sim-python"):
            with self.subTest(engine=engine), (no_c() if engine == "sim-python" else contextlib.nullcontext()):
                imgs, bl, app1, app2 = self.image_set(swap=True)
                m = self.sim(imgs)
                m.uc.mem_write(RES, bytes(0x40))
                old_dfu = bytes(m.flash_mem[self.DFU - boot.FLASH_BASE:][:self.COPY_WORDS * 4])
                m.run_until(5.0)
                self.assertEqual(self.words(m, 1, RES + 0x10), (1,))  # the bootloader copied
                self.assertEqual(self.words(m, 2, RES + 0x20), (2, self.ACTIVE + 0x200))  # app2 runs
                off = self.ACTIVE - boot.FLASH_BASE
                self.assertEqual(bytes(m.flash_mem[off:off + len(old_dfu)]), old_dfu)
                self.assertEqual([im.sha256 for im in imgs.active], [bl.sha256, app2.sha256])
                self.assertTrue(any(e["kind"] == "images" for e in m.events))
                s = m.flash_summary()
                self.assertEqual((s["erase_count"], s["programs"], s["violation_count"]), (2, self.COPY_WORDS, 0))
                poll2 = next(iter(app2.task_polls))
                self.assertEqual(m.polled[poll2], 1)  # app2's hot blocks were installed when it came in
                self.assertEqual(m.idle_pc in app2.wfe, True)

    def test_code_that_ran_is_replaced_and_the_new_code_runs(self):
        # app1 runs, asks for a swap and resets; the bootloader erases and reprograms the flash app1 ran from (its
        # translations must go) and jumps: app2 runs there
        for engine in ("sim-c", "sim-python"):
            with self.subTest(engine=engine), (no_c() if engine == "sim-python" else contextlib.nullcontext()):
                imgs, bl, app1, app2 = self.image_set(swap=True, request=True)
                m = self.sim(imgs)
                m.uc.mem_write(RES, bytes(0x40))
                m.run_until(5.0)
                self.assertEqual([b["cause"] for b in m.boots], ["power-on", "software"])
                self.assertEqual(self.words(m, 1, RES + 0x10), (1,))  # one copy
                self.assertEqual(self.words(m, 1, RES + 0x20), (2,))  # app2 runs where app1 ran
                self.assertEqual([im.sha256 for im in imgs.active], [bl.sha256, app2.sha256])
                self.assertEqual(m.idle_pc in app2.wfe, True)
                self.assertEqual(m.flash_summary()["violation_count"], 0)

    def test_image_set_rejects_a_blob_outside_flash(self):
        bl = boot.Image(self.bootloader(), need_stack=False)
        with self.assertRaises(boot.ToolError):
            boot.ImageSet([bl], blobs=[(0x080F_FFFE, b"1234", "too far")])


def _cal_table_v1(cal_id: int = 7, groups: int = 16) -> bytes:
    """A format-1 calibration table (docs/calibration.md): zero matrices and biases, rails 0..65535."""
    import scenarios as sc

    def zz(v):
        return (v << 1) ^ (v >> 31)
    body = sc.varint(1) + bytes([groups]) + sc.varint(cal_id) + sc.varint(zz(0)) + sc.varint(zz(65535))
    body += bytes(28 * groups)
    return body + boot.crc32c(body).to_bytes(4, "little")


@unittest.skipUnless(os.path.isfile(FW_ELF), f"no firmware ELF at {FW_ELF} (set FW_ELF)")
class RealFirmwareCalibrationStore(unittest.TestCase):
    def test_cal_commit_lands_in_flash(self):
        """CalBegin/CalChunk/CalCommit over the bus: the storage task erases a 16 KiB slot and programs the record
        through embassy-stm32's blocking driver; the record must be in flash (magic, length, CRC-32C) and the
        commit acknowledged Ok."""
        import scenarios as sc
        img = boot.Image(FW_ELF)
        m = sc.new_sim(FW_ELF, img=img)
        r = m.run_until(1.2, timeout_s=120)
        self.assertEqual(r, "time", m.stop_msg)
        versions = sc.bus_versions(m)
        self.assertTrue(versions, "no telemetry from the firmware")
        version = max(versions)
        table = _cal_table_v1()
        cmds = [(10, sc.varint(4) + sc.varint(len(table)) + sc.varint(boot.crc32c(table)))]
        for i, off in enumerate(range(0, len(table), 192)):
            part = table[off:off + 192]
            cmds.append((11 + i, sc.varint(5) + sc.varint(off) + sc.varint(len(part)) + part))
        cmds.append((99, sc.varint(6)))
        before = bytes(m.flash_mem[:0x1_0000])
        t = m.now()
        for tag, body in cmds:
            sc.send_bus(m, sc.command_frame(bytes([version]) + sc.varint(tag) + body), t)
            t += 0.05
        m.run_until(t + 3.0, timeout_s=120)
        acks = {b[1]: b[2:] for k, _, b in sc.raw_messages(bytes(m.bus_tx)) if k == 4 and len(b) >= 3}
        self.assertEqual(acks.get(99), b"\x00", f"CalCommit ack: {acks}")  # Ok
        s = m.flash_summary()
        self.assertEqual(s["violation_count"], 0, s["violations"])
        self.assertEqual(len(s["erases"]), 1, s["erases"])
        snb = s["erases"][0]["sectors"][0]
        start, size = boot.FLASH_SECTORS[snb]
        self.assertEqual(size, 16 << 10)
        self.assertEqual(s["erases"][0]["psize"], "x32")
        rec = bytes(m.flash_mem[start - boot.FLASH_BASE:start - boot.FLASH_BASE + size])
        self.assertNotEqual(rec, before[start - boot.FLASH_BASE:start - boot.FLASH_BASE + size])
        magic, seq, n = struct.unpack_from("<4sII", rec)
        self.assertEqual(magic, b"CAL1")
        self.assertLess(n, 4096)
        self.assertEqual(struct.unpack_from("<I", rec, 12 + n)[0], boot.crc32c(rec[:12 + n]))  # docs/storage.md
        payload = rec[12:12 + n]
        self.assertEqual(struct.unpack_from("<I", payload, len(payload) - 4)[0], boot.crc32c(payload[:-4]))
        self.assertEqual(s["programs"], (12 + n + 4 + 3) // 4)  # one word program per 4 bytes of the record


if __name__ == "__main__":
    unittest.main(verbosity=2)
