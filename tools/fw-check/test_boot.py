#!/usr/bin/env python3
"""Tests of tools/fw-check/boot.py: the chip models, the defmt decoder, and whole runs of tiny synthetic firmwares
(assembled with llvm-mc, linked with rust-lld) that idle, overflow the stack, fault, panic or spin.

    python3 tools/fw-check/test_boot.py            # or: python3 -m pytest tools/fw-check/test_boot.py
    FW_ELF=target/thumbv7em-none-eabihf/fw/firmware python3 tools/fw-check/test_boot.py   # + the real firmware

The synthetic tests are skipped when llvm-mc or rust-lld is missing; the real-firmware test when the ELF is absent.
"""

import argparse
import glob
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import boot  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
POLL = '"_ZN16embassy_executor3raw20TaskStorage$LT$F$GT$4poll17h000000000000000{n}E"'


def find_lld():
    return shutil.which("rust-lld") or shutil.which("ld.lld") or next(
        iter(sorted(glob.glob(os.path.expanduser("~/.rustup/toolchains/*/lib/rustlib/*/bin/rust-lld")))), None)


def args(**kw):
    a = argparse.Namespace(verbose=False, trace_mmio=False, spin_limit=5000, max_stack_percent=80.0,
                           require_iwdg_before_clock=False, json=None)
    a.__dict__.update(kw)
    return a


def thumb_func(name: str, body: str) -> str:
    """The assembly of a global Thumb function `name` whose code is `body` (no newline at the end)."""
    return f""".thumb_func
.global {name}
.type {name},%function
{name}:
{body}
.size {name}, .-{name}"""


def assemble(test: unittest.TestCase, src: str, ld: str, prefix: str) -> str:
    """Assembles `src` (llvm-mc) and links it with the linker script `ld` (rust-lld) in a temporary directory that
    `test` removes at its cleanup; returns the ELF's path."""
    d = tempfile.mkdtemp(prefix=prefix)
    test.addCleanup(shutil.rmtree, d, True)
    for name, text in (("t.s", src), ("t.ld", ld)):
        with open(os.path.join(d, name), "w") as f:
            f.write(text)
    subprocess.run(["llvm-mc", "-triple=thumbv7em-none-eabihf", "-mcpu=cortex-m4", "-filetype=obj",
                    os.path.join(d, "t.s"), "-o", os.path.join(d, "t.o")], check=True)
    subprocess.run([find_lld(), "-flavor", "gnu", "-e", "Reset", "-T", os.path.join(d, "t.ld"),
                    os.path.join(d, "t.o"), "-o", os.path.join(d, "t.elf")], check=True, capture_output=True)
    return os.path.join(d, "t.elf")


class FakeMachine:
    """Enough of boot.Machine for the peripheral models."""

    def __init__(self):
        self.insns, self.events, self.warnings = 0, [], []
        self.t = 0.0
        self.rcc = boot.Rcc(self, "RCC", 0x4002_3800)
        self.flash = boot.FlashIf(self, "FLASH", 0x4002_3C00)

    def now(self):
        return self.t

    def event(self, kind, text):
        self.events.append(kind)

    def warn(self, text):
        self.warnings.append(text)

    def clock_changed(self):
        self.events.append("clock")

    def check_wait_states(self, what):
        pass

    def stop(self, kind, msg):
        self.events.append(("stop", kind))


class ModelTests(unittest.TestCase):
    def test_clock_tree_board_config(self):
        # PLLCFGR / CFGR as embassy writes them for board.rs: HSE 8 MHz, M 4, N 168, P 2, Q 7; PLL, /1 /4 /2
        t = boot.clock_tree(0x0303_0083, 0x0740_2A04, 0x0000_940A)
        self.assertEqual((t["sysclk"], t["hclk"], t["pclk1"], t["pclk2"], t["pll48"]),
                         (168e6, 168e6, 42e6, 84e6, 48e6))
        self.assertEqual((t["tim_apb1"], t["tim_apb2"]), (84e6, 168e6))
        self.assertEqual(boot.clock_tree(0x83, 0x2400_3010, 0)["sysclk"], 16e6)  # reset: HSI

    def test_usart_baud(self):
        self.assertEqual(boot.usart_baud(84e6, 0x2A, 0), 2_000_000)
        self.assertAlmostEqual(boot.usart_baud(42e6, 0x16D, 0), 115_068.5, places=0)
        # OVER8: BRR = mantissa << 4 | fraction (3 bits), baud = f / (8 * mantissa + fraction)
        self.assertEqual(boot.usart_baud(84e6, (5 << 4) | 2, 1 << 15), 84e6 / 42)

    def test_rcc_ready_bits_and_switch(self):
        m = FakeMachine()
        rcc = m.rcc
        self.assertEqual(rcc.read(0x00, 4) & 0x3, 0x3)  # HSION|HSIRDY at reset
        rcc.write(0x00, 4, rcc.read(0x00, 4) | (1 << 16))
        self.assertTrue(rcc.read(0x00, 4) & (1 << 17))  # HSERDY follows HSEON
        rcc.write(0x08, 4, 2)  # SW = PLL while the PLL is off: SWS must not follow
        self.assertEqual((rcc.read(0x08, 4) >> 2) & 3, 0)
        self.assertTrue(m.warnings)
        rcc.write(0x04, 4, 0x0740_2A04)
        rcc.write(0x00, 4, rcc.read(0x00, 4) | (1 << 24))
        self.assertTrue(rcc.read(0x00, 4) & (1 << 25))  # PLLRDY
        rcc.write(0x08, 4, 0x0000_9402)
        self.assertEqual((rcc.read(0x08, 4) >> 2) & 3, 2)  # SWS = PLL
        rcc.write(0x00, 4, rcc.read(0x00, 4) & ~(1 << 24))  # PLL in use: stays on
        self.assertTrue(rcc.read(0x00, 4) & (1 << 24))
        rcc.write(0x04, 4, 0x2400_3010)  # PLLCFGR while the PLL is on: ignored
        self.assertEqual(rcc.read(0x04, 4), 0x0740_2A04)
        # reset flags: POR|PIN|BOR at power-on, RMVF clears them; LSIRDY follows LSION
        self.assertEqual(rcc.read(0x74, 4) >> 24, 0x0E)
        rcc.write(0x74, 4, rcc.read(0x74, 4) | (1 << 24) | 1)
        self.assertEqual(rcc.read(0x74, 4), 0x3)
        self.assertEqual(rcc.read(0x76, 2), 0)  # halfword access

    def test_iwdg_lock_and_keys(self):
        m = FakeMachine()
        iw = boot.Iwdg(m, "IWDG", 0x4000_3000)
        iw.write(0x04, 4, 4)
        self.assertEqual(iw.read(0x04, 4), 0)  # locked
        iw.write(0x00, 4, 0x5555)
        iw.write(0x04, 4, 4)
        iw.write(0x08, 4, 3999)
        iw.write(0x00, 4, 0xCCCC)
        self.assertEqual([k for k, _, _ in iw.keys], [0x5555, 0xCCCC])
        self.assertAlmostEqual(iw.timeout_s(), 8.0)
        self.assertIn("iwdg_start", m.events)

    def test_timer_counts_virtual_time(self):
        m = FakeMachine()
        m.rcc.write(0x08, 4, 0)  # HSI: APB1 timers at 16 MHz
        tim = boot.Timer(m, "TIM5", 0x4000_0C00)
        tim.write(0x28, 4, 999)  # PSC: 16 kHz
        tim.write(0x00, 4, 1)  # CEN
        m.t = 0.010
        self.assertEqual(tim.read(0x24, 4), 160)
        tim.write(0x24, 4, 5)
        m.t = 0.0101
        self.assertEqual(tim.read(0x24, 4), 6)

    def test_adc_conversion(self):
        m = FakeMachine()
        m.adc_conversions = 0
        adc = boot.Adc(m, "ADC", 0x4001_2000)
        adc.write(0x34, 4, 17)  # SQR3: VREFINT
        adc.write(0x08, 4, (1 << 30) | 1)  # SWSTART
        self.assertEqual(adc.read(0x00, 4) & 0x12, 0x12)
        self.assertEqual(adc.read(0x4C, 4), boot.VREFINT_CAL)
        self.assertEqual(adc.read(0x00, 4) & 0x2, 0)  # reading DR clears EOC

    def test_gpio_bsrr(self):
        g = boot.Gpio(FakeMachine(), "GPIOC", 0x4002_0800)
        g.write(0x00, 4, 1 << 26)  # PC13 output
        g.write(0x18, 4, 1 << 13)
        self.assertEqual(g.read(0x10, 4), 1 << 13)
        g.write(0x18, 4, 1 << 29)
        self.assertEqual(g.read(0x14, 4), 0)

    def test_names(self):
        self.assertEqual(boot.tidy_rust_name("embassy_executor::raw::TaskStorage$LT$F$GT$::poll::h30de314622d15a9d"),
                         "embassy_executor::raw::TaskStorage<F>::poll")
        self.assertEqual(boot.demangle_legacy("_ZN8firmware5board4init17h0123456789abcdefE"),
                         "firmware::board::init::h0123456789abcdef")


class DefmtTests(unittest.TestCase):
    def decoder(self, strings):
        d = boot.Defmt.__new__(boot.Defmt)
        d.strings = strings
        d.timestamp = "{=u64:us}"
        return d

    def test_frame(self):
        d = self.decoder({10: ("defmt_info", "boot: clock {}, reset flags {=u8:#x}, fault {}"),
                          71: ("defmt_derived", "Hse8MHz|HsiFallback"), 6: ("defmt_prim", "None|Some({=?})"),
                          7: ("defmt_prim", "{=[?;2]}"), 89: ("defmt_derived", "Empty|Invalid|Valid({=u32})")})
        frame = struct.pack("<HQHBBHB", 10, 1250, 71, 1, 0x07, 6, 0)
        e = d.decode(frame)
        self.assertEqual((e["level"], e["timestamp"], e["text"]),
                         ("info", "0.001250", "boot: clock HsiFallback, reset flags 0x7, fault None"))
        e = d.decode(struct.pack("<HQHHBBI", 10, 0, 71, 7, 0, 2, 9) + b"")
        self.assertIn("undecoded", d.decode(b"\x63\x00").get("text"))  # unknown index: shown raw

    def test_str_and_debug(self):
        d = self.decoder({1: ("defmt_error", "panicked at '{=str}' {=__internal_Display}")})
        frame = struct.pack("<HQI", 1, 0, 3) + b"abc" + b"x y\xff"
        self.assertEqual(d.decode(frame)["text"], "panicked at 'abc' x y")


class BusAndFrameTests(unittest.TestCase):
    def test_crc32c_check_value(self):
        self.assertEqual(boot.crc32c(b"123456789"), 0xE3069283)  # docs/fpga-link.md

    def test_synth_frames(self):
        d = boot.synth_frames(3)
        self.assertEqual(len(d), 720)
        for i in range(3):
            f = d[240 * i:240 * (i + 1)]
            self.assertEqual(f[:4], bytes([0x1A, 0xCF, 0xFC, 0x1D]))
            self.assertEqual(struct.unpack_from("<H", f, 4)[0], i)
            self.assertEqual(struct.unpack_from("<I", f, 236)[0], boot.crc32c(f[:236]))

    def test_kiss_csp_fused(self):
        body = bytes([2, 0, 0x85, 0x01])  # version 2, Telemetry::Fused, seq 133 (varint)
        header = bytes([0x82, 0xA2, 0xA1, 0x00])
        pkt = header + body + boot.crc32c(body).to_bytes(4, "big")
        esc = pkt.replace(b"\xdb", b"\xdb\xdd").replace(b"\xc0", b"\xdb\xdc")
        frames = list(boot.kiss_frames(b"\xc0\x00" + esc + b"\xc0"))
        self.assertEqual(frames, [pkt])
        info = boot.decode_bus_message(frames[0])
        self.assertEqual((info["kind"], info["seq"], info["link_crc_ok"]), ("Fused", 133, True))


@unittest.skipUnless(shutil.which("llvm-mc") and find_lld() and shutil.which("llvm-objdump"),
                     "needs llvm-mc, rust-lld and llvm-objdump")
class SyntheticFirmwareTests(unittest.TestCase):
    """Tiny firmwares with the shape boot.py expects: a vector table, `TaskStorage<F>::poll` symbols, a WFE loop."""

    LD = """MEMORY { FLASH (rx) : ORIGIN = 0x08000000, LENGTH = 1024K  RAM (rwx) : ORIGIN = 0x20000000, LENGTH = 128K }
_stack_end = 0x20000000;
_stack_start = 0x20001000;
SECTIONS {
  .vector_table ORIGIN(FLASH) : { KEEP(*(.vector_table)) } > FLASH
  .text : { *(.text .text.*) } > FLASH
}
"""

    def build(self, body: str, extra: str = "") -> str:
        polls = "".join(f"""
.thumb_func
.type {POLL.format(n=n)},%function
{POLL.format(n=n)}:
  push {{r7, lr}}
  pop {{r7, pc}}
.size {POLL.format(n=n)}, .-{POLL.format(n=n)}
""" for n in (1, 2))
        src = f""".syntax unified
.cpu cortex-m4
.thumb
.section .vector_table,"a",%progbits
.word _stack_start
.word Reset
.word DefaultHandler
.word HardFault
.rept 12
.word DefaultHandler
.endr
.text
{thumb_func("Reset", body)}
.thumb_func
.global DefaultHandler
.type DefaultHandler,%function
DefaultHandler: b DefaultHandler
.size DefaultHandler, .-DefaultHandler
.thumb_func
.global HardFault
.type HardFault,%function
HardFault: b HardFault
.size HardFault, .-HardFault
.thumb_func
.global rust_begin_unwind
.type rust_begin_unwind,%function
rust_begin_unwind: b rust_begin_unwind
.size rust_begin_unwind, .-rust_begin_unwind
{polls}
{extra}
"""
        return assemble(self, src, self.LD, "boot-test-")

    def run_elf(self, path, **kw):
        img = boot.Image(path)
        m = boot.Machine(img, args(**kw))
        m.run(10.0, 5_000_000)
        return img, m

    CALL_POLLS = f"""  bl {POLL.format(n=1)}
  bl {POLL.format(n=2)}
"""

    def test_idle_after_sev_and_polls(self):
        img, m = self.run_elf(self.build(self.CALL_POLLS + "  sev\n1: wfe\n  b 1b\n"))
        self.assertEqual(m.stop_kind, "idle", m.stop_msg)
        self.assertEqual(m.wfe_wakeups, 1)  # the SEV's event let the first WFE through
        self.assertEqual(len(img.task_polls), 2)
        self.assertTrue(all(m.polled[a] for a in img.task_polls))
        results, fig = boot.check(m, args())
        by = {r["name"]: r for r in results}
        self.assertTrue(by["every task polled before idle"]["ok"])
        self.assertTrue(by["stack high-water mark"]["ok"])
        self.assertFalse(by["IWDG started"]["ok"])  # this firmware never starts it

    def test_task_not_polled(self):
        img, m = self.run_elf(self.build(f"  bl {POLL.format(n=1)}\n1: wfe\n  b 1b\n"))
        results, fig = boot.check(m, args())
        self.assertEqual(len(fig["tasks"]["not_polled"]), 1)
        self.assertFalse(next(r for r in results if r["name"] == "every task polled before idle")["ok"])

    def test_stack_overflow_names_the_frame(self):
        img, m = self.run_elf(self.build("  bl big\n1: wfe\n  b 1b\n", """
.thumb_func
.type big,%function
big:
  push {r7, lr}
  sub.w sp, sp, #8192
  str r0, [sp]
  add.w sp, sp, #8192
  pop {r7, pc}
.size big, .-big
"""))
        self.assertEqual(m.stop_kind, "stack-overflow", m.stop_msg)
        self.assertIn("sub.w sp, sp, #8192", m.stop_msg)
        self.assertIn("in big+", m.stop_msg)
        self.assertIsNotNone(m.overflow)

    def test_unmapped_access_is_a_fault(self):
        img, m = self.run_elf(self.build("  ldr r0, =0x60000000\n  ldr r1, [r0]\n1: wfe\n  b 1b\n"))
        self.assertEqual(m.stop_kind, "fault", m.stop_msg)
        self.assertIn("0x60000000", m.stop_msg)
        # just below SRAM (where a flip-link overflow goes) is unmapped too
        img, m = self.run_elf(self.build("  ldr r0, =0x1FFFFFF0\n  ldr r1, [r0]\n1: wfe\n  b 1b\n"))
        self.assertEqual(m.stop_kind, "fault", m.stop_msg)
        # the factory calibration words are there
        img, m = self.run_elf(self.build("  ldr r0, =0x1FFF7A2A\n  ldrh r1, [r0]\n1: wfe\n  b 1b\n"))
        self.assertEqual(m.stop_kind, "idle", m.stop_msg)

    def test_panic_handler_is_a_failure(self):
        img, m = self.run_elf(self.build("  bl rust_begin_unwind\n"))
        self.assertEqual(m.stop_kind, "trap", m.stop_msg)
        self.assertIn("panic", m.stop_msg)

    def test_spin_on_status_bit_is_reported(self):
        # wait for RCC_CR bit 30 (reserved: never set)
        img, m = self.run_elf(self.build("  ldr r0, =0x40023800\n1: ldr r1, [r0]\n  lsls r1, r1, #1\n  bpl 1b\n"
                                         "2: wfe\n  b 2b\n"), spin_limit=2000)
        self.assertEqual(m.stop_kind, "stuck", m.stop_msg)
        self.assertIn("RCC+0x000", m.stop_msg)
        self.assertIn("Reset+", m.stop_msg)

    def test_sys_reset_is_a_failure(self):
        img, m = self.run_elf(self.build("  ldr r0, =0xE000ED0C\n  ldr r1, =0x05FA0004\n  str r1, [r0]\n"
                                         "1: wfe\n  b 1b\n"))
        self.assertEqual(m.stop_kind, "reset", m.stop_msg)


FW_ELF = os.environ.get("FW_ELF", os.path.join(ROOT, "target/thumbv7em-none-eabihf/fw/firmware"))


@unittest.skipUnless(os.path.isfile(FW_ELF), f"no firmware ELF at {FW_ELF}")
class RealFirmwareTest(unittest.TestCase):
    def test_boot_reaches_idle(self):
        img = boot.Image(FW_ELF)
        m = boot.Machine(img, args(spin_limit=200_000))
        m.run(30.0, 50_000_000)
        results, fig = boot.check(m, args())
        failed = [f"{r['name']}: {r['measured']}" for r in results if not r["ok"]]
        self.assertEqual(failed, [], m.stop_msg)

    def test_frames_reach_the_bus(self):
        img = boot.Image(FW_ELF)
        a = args(spin_limit=200_000, fused=1)
        m = boot.Machine(img, a)
        m.run(30.0, 50_000_000)
        results, fig = boot.check(m, a)
        m.frames_phase(boot.synth_frames(100), 604.8, 100, 1)
        boot.check_frames(m, a, results, fig)
        self.assertIsNotNone(m.first_fused, m.frames_result)
        self.assertTrue(m.first_fused["link_crc_ok"])
        failed = [f"{r['name']}: {r['measured']}" for r in results if not r["ok"]]
        self.assertEqual(failed, [])


if __name__ == "__main__":
    unittest.main(verbosity=2)
