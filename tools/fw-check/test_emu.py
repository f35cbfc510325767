#!/usr/bin/env python3
"""Tests of tools/fw-check/emu.py (scenario mode): the IWDG, SysTick, CSS and USART-error models on their own, and
exception delivery, preemption, priorities, faults, stacking failure, resets and fast-forwarded spins on tiny
hand-assembled Thumb firmwares (llvm-mc + rust-lld, as test_boot.py; skipped when those are missing).

    python3 -m pytest -q tools/fw-check/test_emu.py
"""

import os
import shutil
import struct
import sys
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import boot  # noqa: E402
import emu  # noqa: E402
import test_boot  # noqa: E402
from test_boot import FakeMachine, args, assemble, find_lld, thumb_func  # noqa: E402

RES = 0x2000_4000  # where the test firmwares write their results (SRAM, kept across resets)


class FakeMem:
    """The unicorn engine as the DMA model writes to it: a byte map."""

    def __init__(self):
        self.mem = {}

    def mem_write(self, a, d):
        for i, b in enumerate(d):
            self.mem[a + i] = b


class FakeSim(FakeMachine):
    """Enough of emu.Sim for the peripheral models."""

    def __init__(self):
        super().__init__()
        self.rcc = emu.Rcc(self, "RCC", 0x4002_3800)
        self.lsi_hz = 32_000.0
        self.hz = 16e6
        self.pended = []
        self.dead = False
        self.active, self.sys_pending = [], set()

    def hse_ok(self):
        return not self.dead

    def pend_exception(self, exc):
        self.pended.append(exc)

    def poke(self):
        pass


class ModelTests(unittest.TestCase):
    def test_iwdg_counts_down_on_the_lsi(self):
        m = FakeSim()
        iw = emu.Iwdg(m, "IWDG", 0x4000_3000)
        self.assertEqual(iw.expiry(), float("inf"))
        iw.write(0x00, 4, 0x5555)
        iw.write(0x04, 4, 4)  # /64
        iw.write(0x08, 4, 3999)
        iw.write(0x00, 4, 0xCCCC)  # starts from 0xFFF (RM0090 21.3.1)
        self.assertAlmostEqual(iw.expiry(), 4096 * 64 / 32_000)
        m.t = 1.0
        iw.write(0x00, 4, 0xAAAA)  # reload from RLR
        self.assertAlmostEqual(iw.expiry(), 1.0 + 4000 * 64 / 32_000)  # 8 s
        m.t = 1.0 + 64 / 32_000 * 10.5
        self.assertEqual(iw.counter(), 3999 - 10)
        m.lsi_hz = 40_000.0  # the LSI is a parameter (17-47 kHz over parts and temperature)
        self.assertAlmostEqual(iw.expiry(), 1.0 + 4000 * 64 / 40_000)

    def test_systick(self):
        m = FakeSim()
        m.hz = 8e6
        p = emu.Ppb(m, "PPB", 0xE000_0000)
        p.write(0xE014, 4, 999)  # RVR
        p.write(0xE018, 4, 123)  # CVR: any write clears it
        self.assertEqual(p.read(0xE018, 4), 0)
        p.write(0xE010, 4, 0b111)  # ENABLE | TICKINT | CLKSOURCE = processor clock
        m.t = 0.5 / 8e6
        self.assertEqual(m.pended, [])
        m.t = 500 / 8e6  # 1 tick loads 999, then 499 more
        self.assertEqual(p.read(0xE018, 4), 999 - 499)
        self.assertEqual(m.pended, [])
        m.t = 1000 / 8e6  # 1 + 999 ticks: reaches 0
        self.assertEqual(p.read(0xE018, 4), 0)
        self.assertEqual(m.pended, [emu.SYSTICK])
        self.assertTrue(p.read(0xE010, 4) & (1 << 16))  # COUNTFLAG, cleared by the read
        self.assertFalse(p.read(0xE010, 4) & (1 << 16))
        self.assertAlmostEqual(p.st_next_event(), 2000 / 8e6)
        # CLKSOURCE = 0: HCLK / 8
        p.write(0xE010, 4, 0b011)
        t0 = m.t
        m.t = t0 + 8 * 1000 / 8e6
        p.st_update()
        self.assertEqual(m.pended, [emu.SYSTICK, emu.SYSTICK])

    def test_css_moves_sysclk_to_hsi_and_raises_nmi(self):
        m = FakeSim()
        rcc = m.rcc
        rcc.write(0x04, 4, 0x0740_2A04 | (1 << 22))  # PLL from HSE
        rcc.write(0x00, 4, rcc.read(0x00, 4) | (1 << 16) | (1 << 19))  # HSEON, CSSON
        rcc.write(0x00, 4, rcc.read(0x00, 4) | (1 << 24))
        rcc.write(0x08, 4, 0x0000_9402)
        self.assertEqual((rcc.read(0x08, 4) >> 2) & 3, 2)
        self.assertEqual(rcc.hse_failure(), "css")
        cr, cfgr, cir = rcc.read(0x00, 4), rcc.read(0x08, 4), rcc.read(0x0C, 4)
        self.assertFalse(cr & ((1 << 16) | (1 << 17) | (1 << 24) | (1 << 25)))  # HSE and PLL off
        self.assertEqual(cfgr & 0xF, 0)  # SW = SWS = HSI
        self.assertTrue(cir & (1 << 7))  # CSSF
        self.assertEqual(m.pended, [emu.NMI])
        rcc.write(0x0C, 4, 1 << 23)  # CSSC
        self.assertFalse(rcc.read(0x0C, 4) & (1 << 7))

    def test_css_off_halts_a_core_on_the_crystal(self):
        m = FakeSim()
        rcc = m.rcc
        rcc.write(0x00, 4, rcc.read(0x00, 4) | (1 << 16))
        rcc.write(0x08, 4, 1)  # SYSCLK = HSE
        self.assertEqual(rcc.hse_failure(), "halt")
        self.assertEqual(m.pended, [])

    def test_dead_crystal_never_ready(self):
        m = FakeSim()
        m.dead = True
        rcc = m.rcc
        rcc.write(0x00, 4, rcc.read(0x00, 4) | (1 << 16))
        self.assertFalse(rcc.read(0x00, 4) & (1 << 17))
        rcc.write(0x08, 4, 1)  # SW = HSE: not ready, SWS stays HSI
        self.assertEqual((rcc.read(0x08, 4) >> 2) & 3, 0)

    def test_usart_framing_errors(self):
        m = FakeSim()
        u = emu.Usart(m, "USART1", 0x4001_1000)
        u.write(0x0C, 4, (1 << 13) | 0xC)  # UE TE RE, no DMAR
        u.write(0x14, 4, 1)  # EIE
        u.byte_in(None, 2, 0x55, emu.FE)
        self.assertTrue(u.read(0x00, 4) & (emu.FE | emu.RXNE) == emu.FE | emu.RXNE)
        self.assertTrue(u.irq_pending())  # EIE with FE
        u.byte_in(None, 2, 0x66)  # RXNE still set: overrun
        sr = u.read(0x00, 4)
        self.assertTrue(sr & emu.ORE)
        self.assertEqual(u.read(0x04, 4), 0x55)  # SR then DR: clears FE, ORE, RXNE
        self.assertFalse(u.read(0x00, 4) & (emu.FE | emu.ORE | emu.RXNE))
        self.assertFalse(u.irq_pending())
        u.write(0x14, 4, 0)
        u.byte_in(None, 2, 0x77, emu.FE)
        self.assertFalse(u.irq_pending())  # without EIE no interrupt

    def test_usart_error_bytes_still_go_to_the_dma_ring(self):
        m = FakeSim()
        m.uc = FakeMem()
        d = emu.Dma(m, "DMA2", 0x4002_6400)
        b = 0x10 + 0x18 * 2
        d.regs.update({b + 4: 8, b + 0xC: 0x2000_0000, b: 1 | (1 << 8)})
        d.ring_len[2] = 8
        u = emu.Usart(m, "USART1", 0x4001_1000)
        u.write(0x0C, 4, (1 << 13) | 0xC)
        u.write(0x14, 4, 0x41)  # DMAR | EIE
        u.bytes_in(d, 2, b"abcdefghij", emu.FE)
        self.assertEqual(bytes(m.uc.mem[0x2000_0000 + i] for i in range(8)), b"ijcdefgh")
        self.assertEqual(d.regs[b + 4], 6)
        self.assertTrue(u.read(0x00, 4) & emu.FE)
        self.assertTrue(d.isr[0] & (1 << 21))  # TCIF2 (lapped)

    def test_dma_stream_restart_as_the_f4(self):
        # AN4031: a stream disabled mid-transfer sets TCIF and keeps NDTR; enabled again it restarts at M0AR with
        # that NDTR; the circular reload brings back the programmed length
        m = FakeSim()
        m.uc = FakeMem()
        d = emu.Dma(m, "DMA2", 0x4002_6400)
        b = 0x10 + 0x18 * 2
        d.write(b + 4, 4, 8)  # NDTR programmed while disabled
        d.write(b + 0xC, 4, 0x2000_0000)
        d.write(b, 4, 1 | (1 << 8))  # EN | CIRC, P2M
        d.receive(2, b"abc")
        self.assertEqual(d.regs[b + 4], 5)
        d.write(b, 4, 1 << 8)  # disabled mid-transfer: TCIF
        self.assertTrue(d.isr[0] & (1 << 21))
        d.write(0x08, 4, 1 << 21)
        d.write(b, 4, 1 | (1 << 8))  # enabled again, NDTR untouched: restarts at M0AR with NDTR 5
        d.receive(2, b"XYZUVW")
        self.assertEqual(bytes(m.uc.mem[0x2000_0000 + i] for i in range(5)), b"WYZUV")  # 5 bytes, wrap, W at 0
        self.assertEqual(d.regs[b + 4], 7)  # reloaded with the programmed 8, one byte since
        self.assertTrue(d.isr[0] & (1 << 21))

    def test_command_encoding(self):
        import scenarios
        self.assertEqual(scenarios.varint(300), b"\xac\x02")
        self.assertEqual(scenarios.csp_v1_header(2, 1, 10, 11, 10), bytes([0x82, 0xA2, 0xCA, 0x00]))
        f = scenarios.allan_request(4, tag=1, first=0, count=102)
        pkt = next(boot.kiss_frames(f))
        self.assertEqual(pkt[4:-4], bytes([4, 1, 7, 0, 102]))
        self.assertEqual(int.from_bytes(pkt[-4:], "big"), boot.crc32c(pkt[4:-4]))
        self.assertEqual(scenarios.kiss(b"\xc0\xdb"), b"\xc0\x00\xdb\xdc\xdb\xdd\xc0")


# A HardFault handler's start: CFSR and HFSR to RES[0] and RES[1] (r0 keeps RES).
HARDFAULT_SAVES_CFSR_HFSR = f"""  ldr r0, ={RES}
  ldr r1, =0xE000ED28
  ldr r2, [r1]
  str r2, [r0]
  ldr r2, [r1, #4]
  str r2, [r0, #4]
"""

VECTORS = ["NMI_H", "HardFault_H", "MemManage_H", "BusFault_H", "UsageFault_H", "0", "0", "0", "0", "SVC_H",
           "0", "0", "PendSV_H", "SysTick_H"] + ["IRQ_H"] * 8


@unittest.skipUnless(shutil.which("llvm-mc") and find_lld() and shutil.which("llvm-objdump"),
                     "needs llvm-mc, rust-lld and llvm-objdump")
class SyntheticSimTests(unittest.TestCase):
    """Tiny firmwares run by emu.Sim: handlers write what they see to RES.. (SRAM survives resets)."""

    LD = test_boot.SyntheticFirmwareTests.LD
    DEFAULT_HANDLERS = {"NMI_H": "b .", "HardFault_H": "b .", "MemManage_H": "b .", "BusFault_H": "b .",
                        "UsageFault_H": "b .", "SVC_H": "b .", "PendSV_H": "bx lr", "SysTick_H": "bx lr",
                        "IRQ_H": "bx lr"}

    def build(self, reset: str, **handlers) -> str:
        h = dict(self.DEFAULT_HANDLERS, **handlers)
        funcs = "".join(f"\n{thumb_func(name, body)}\n" for name, body in h.items())
        src = f""".syntax unified
.cpu cortex-m4
.fpu fpv4-sp-d16
.thumb
.section .vector_table,"a",%progbits
.word _stack_start
.word Reset
{chr(10).join('.word ' + v for v in VECTORS)}
.text
{thumb_func("Reset", reset)}
{funcs}
.ltorg
"""
        return assemble(self, src, self.LD, "emu-test-")

    def sim(self, path, **kw):
        m = emu.Sim(boot.Image(path), args(spin_limit=5000), **kw)
        m.power_on()
        return m

    def words(self, m, n, at=RES):
        return struct.unpack(f"<{n}I", bytes(m.uc.mem_read(at, 4 * n)))

    # SysTick every 1000 cycles at 16 MHz (HSI), TICKINT, processor clock
    SYSTICK_ON = """  ldr r0, =0xE000E014
  ldr r1, =999
  str r1, [r0]
  ldr r0, =0xE000E010
  movs r1, #7
  str r1, [r0]
"""

    def test_systick_preempts_thread_code_and_ipsr_is_visible(self):
        # the thread sums 1..N in registers while SysTick fires; the handler counts and stores IPSR and the
        # stacked PC; the thread's registers must come out right
        path = self.build(f"""  ldr r7, ={RES}
  movs r0, #0
  str r0, [r7]
{self.SYSTICK_ON}
  movs r4, #0
  movs r5, #0
  ldr r6, =200000
1: adds r5, r5, #1
  adds r4, r4, r5
  cmp r5, r6
  bne 1b
  str r4, [r7, #4]
  mrs r0, ipsr
  str r0, [r7, #12]
2: wfe
  b 2b
""", SysTick_H=f"""  ldr r0, ={RES}
  ldr r1, [r0]
  adds r1, #1
  str r1, [r0]
  mrs r2, ipsr
  str r2, [r0, #8]
  ldr r3, [sp, #24]
  str r3, [r0, #16]
  mov r3, lr
  str r3, [r0, #20]
  bx lr""")
        m = self.sim(path)
        r = m.run_until(0.1)
        self.assertEqual(r, "time", m.stop_msg)
        ticks, total, ipsr_h, ipsr_t, stacked_pc, exc_ret = self.words(m, 6)
        self.assertEqual(total, (200000 * 200001 // 2) & 0xFFFF_FFFF)
        self.assertGreater(ticks, 100)  # 800k+ instructions at one tick per 1000 cycles
        self.assertEqual(ipsr_h, 15)
        self.assertEqual(ipsr_t, 0)
        self.assertEqual(exc_ret, 0xFFFF_FFF9)  # thread, MSP, basic frame
        name, _ = m.img.func_at(stacked_pc)
        self.assertEqual(name, "Reset")
        self.assertEqual(m.exc_counts[emu.SYSTICK], ticks)

    def test_priorities_nesting_and_masking(self):
        # SysTick (priority 0xF0) pends IRQ0 (priority 0x10) and IRQ1 (0xF0, same as SysTick: must wait);
        # IRQ0 preempts at once (nested), IRQ1 runs after SysTick returns. A log of IPSR values shows the order.
        log = f"""  ldr r0, ={RES + 0x40}
  ldr r1, [r0]
  mrs r2, ipsr
  str r2, [r0, r1, lsl #2]
  adds r1, #1
  str r1, [r0]
"""
        path = self.build(f"""  ldr r0, =0xE000ED20
  ldr r1, =0xF0000000
  str r1, [r0]
  ldr r0, =0xE000E400
  ldr r1, =0x0000F010
  str r1, [r0]
  ldr r0, =0xE000E100
  movs r1, #3
  str r1, [r0]
  ldr r0, ={RES + 0x40}
  movs r1, #1
  str r1, [r0]
  cpsid i
{self.SYSTICK_ON}
  ldr r6, =3000
1: subs r6, #1
  bne 1b
  cpsie i
2: wfe
  b 2b
""", SysTick_H=f"""  push {{r4, lr}}
  ldr r0, =0xE000E010
  movs r1, #0
  str r1, [r0]
{log}
  ldr r0, =0xE000EF00
  movs r1, #1
  str r1, [r0]
  isb
  movs r1, #0
  str r1, [r0]
  isb
{log}
  pop {{r4, pc}}""", IRQ_H=f"""{log}
  bx lr""")
        m = self.sim(path)
        m.run_until(0.01)
        n = self.words(m, 1, RES + 0x40)[0]
        seq = self.words(m, n, RES + 0x40)[1:]
        # SysTick (15), IRQ0 (16) nested, SysTick continues (15), then IRQ1 (17) after it returns
        self.assertEqual(list(seq), [15, 16, 15, 17])
        # SysTick was pended while PRIMASK was set: taken only after cpsie
        self.assertEqual(m.exc_counts[emu.SYSTICK], 1)

    def test_bad_address_hardfault_then_sysresetreq_keeps_ram(self):
        hf = f"""  ldr r0, ={RES}
  ldr r1, =0xE000ED28
  ldr r2, [r1]
  str r2, [r0, #4]
  ldr r2, [r1, #4]
  str r2, [r0, #8]
  ldr r2, [r1, #16]
  str r2, [r0, #12]
  ldr r2, [sp, #24]
  str r2, [r0, #16]
  mrs r2, ipsr
  str r2, [r0, #20]
  ldr r1, =0xE000ED0C
  ldr r2, =0x05FA0004
  str r2, [r1]
  dsb
1: b 1b"""
        path = self.build(f"""  ldr r7, ={RES}
  ldr r0, [r7, #24]
  adds r0, #1
  str r0, [r7, #24]
  ldr r1, =0x40023874
  ldr r2, [r1]
  lsls r3, r0, #2
  adds r3, r3, r7
  str r2, [r3, #28]
  ldr r2, =0x01000000
  str r2, [r1]
  cmp r0, #1
  bne 2f
  ldr r0, =0x60000000
fault_here:
  ldr r1, [r0]
2: wfe
  b 2b
""", HardFault_H=hf)
        m = self.sim(path)
        m.uc.mem_write(RES, bytes(64))
        r = m.run_until(0.05)
        self.assertEqual(r, "time", m.stop_msg)
        _, cfsr, hfsr, bfar, pc, ipsr, boots, _, csr1, csr2 = self.words(m, 10)
        self.assertEqual(boots, 2)  # RAM kept: the second boot saw the first one's count
        self.assertEqual(cfsr, emu.PRECISERR | emu.BFARVALID)
        self.assertEqual(hfsr, emu.HFSR_FORCED)
        self.assertEqual(bfar, 0x6000_0000)
        self.assertEqual(pc, m.img.addr_of["fault_here"] & ~1)
        self.assertEqual(ipsr, 3)
        self.assertEqual(csr1 >> 24, (emu.PORRSTF | emu.PINRSTF | emu.BORRSTF) >> 24)
        self.assertEqual(csr2 >> 24, (emu.SFTRSTF | emu.PINRSTF) >> 24)  # cleared by RMVF in between
        self.assertEqual([b["cause"] for b in m.boots], ["power-on", "software"])
        # the fault registers are back at their reset values in the new boot
        self.assertEqual(m.ppb.regs.get(m.ppb.CFSR, 0), 0)

    def test_stacking_failure_enters_hardfault_with_sp_unchanged(self):
        # SP just above the bottom of SRAM; a pended IRQ cannot push its 32-byte frame below 0x2000_0000
        path = self.build("""  ldr r0, =0xE000E100
  movs r1, #1
  str r1, [r0]
  ldr r0, =0x20000010
  mov sp, r0
  ldr r0, =0xE000EF00
  movs r1, #0
  str r1, [r0]
1: wfe
  b 1b
""", HardFault_H=f"""  mov r1, sp
  ldr r0, ={RES}
  str r1, [r0]
  ldr r1, =0xE000ED28
  ldr r2, [r1]
  str r2, [r0, #4]
  ldr r2, [r1, #4]
  str r2, [r0, #8]
  mov r2, lr
  str r2, [r0, #12]
  ldr r1, =0x20001000
  mov sp, r1
  push {{r0}}
1: b 1b""")
        m = self.sim(path)
        m.run_until(0.01)
        sp, cfsr, hfsr, lr = self.words(m, 4)
        self.assertEqual(sp, 0x2000_0010)
        self.assertEqual(cfsr, emu.STKERR)
        self.assertEqual(hfsr, emu.HFSR_FORCED)
        self.assertEqual(lr & 0xFFFF_FFF0, 0xFFFF_FFF0)

    def test_iwdg_reset_after_its_timeout_with_a_spinning_core(self):
        # IWDG /16, RLR 4095: 4096*16/LSI = 1.64 s; reloaded once, then the core spins in `b .` (26 M instructions
        # at 16 MHz: fast-forwarded once seen as a spin)
        path = self.build(f"""  ldr r7, ={RES}
  ldr r0, [r7]
  adds r0, #1
  str r0, [r7]
  ldr r1, =0x40023874
  ldr r2, [r1]
  str r2, [r7, #4]
  ldr r2, =0x01000000
  str r2, [r1]
  cmp r0, #2
  beq 2f
  ldr r1, =0x40003000
  ldr r2, =0x5555
  str r2, [r1]
  movs r2, #2
  str r2, [r1, #4]
  ldr r2, =4095
  str r2, [r1, #8]
  ldr r2, =0xCCCC
  str r2, [r1]
  ldr r2, =0xAAAA
  str r2, [r1]
1: b 1b
2: wfe
  b 2b
""")
        m = self.sim(path, lsi_hz=40_000.0)
        m.uc.mem_write(RES, bytes(16))
        r = m.run_until(2.0, timeout_s=30)
        self.assertEqual(r, "time", m.stop_msg)
        boots, csr = self.words(m, 2)
        self.assertEqual(boots, 2)
        self.assertEqual(csr >> 24, (emu.IWDGRSTF | emu.PINRSTF) >> 24)
        self.assertEqual(m.boots[1]["cause"], "iwdg")
        self.assertAlmostEqual(m.boots[1]["t"], 4096 * 16 / 40_000, delta=1e-3)
        self.assertTrue(any(e["kind"] == "spin" for e in m.events))

    def test_fault_in_hardfault_locks_up_until_the_iwdg(self):
        path = self.build(f"""  ldr r7, ={RES}
  ldr r0, [r7]
  adds r0, #1
  str r0, [r7]
  cmp r0, #1
  bne 2f
  ldr r1, =0x40003000
  ldr r2, =0x5555
  str r2, [r1]
  movs r2, #0
  str r2, [r1, #4]
  movs r2, #100
  str r2, [r1, #8]
  ldr r2, =0xCCCC
  str r2, [r1]
  ldr r2, =0xAAAA
  str r2, [r1]
  ldr r0, =0x60000000
  ldr r1, [r0]
2: wfe
  b 2b
""", HardFault_H="""  ldr r0, =0x60000004
  ldr r1, [r0]
1: b 1b""")
        m = self.sim(path)
        m.uc.mem_write(RES, bytes(8))
        m.run_until(0.05)
        self.assertEqual(self.words(m, 1)[0], 2)
        self.assertEqual([b["cause"] for b in m.boots], ["power-on", "iwdg"])
        self.assertTrue(any(e["kind"] == "lockup" for e in m.events))
        self.assertAlmostEqual(m.boots[1]["t"], 101 * 4 / 32_000, delta=2e-4)

    def test_reset_cap(self):
        path = self.build("""  ldr r1, =0xE000ED0C
  ldr r2, =0x05FA0004
  str r2, [r1]
1: b 1b
""")
        m = self.sim(path, max_resets=3)
        self.assertEqual(m.run_until(1.0), "reset-cap")
        self.assertEqual(len(m.boots), 5)

    def test_css_nmi(self):
        # HSE on with CSSON, SYSCLK = HSE; the crystal fails at 1 ms: the NMI records CIR and CFGR, clears CSSF
        path = self.build("""  ldr r1, =0x40023800
  ldr r2, [r1]
  orr r2, r2, #0x90000
  str r2, [r1]
1: ldr r2, [r1]
  tst r2, #0x20000
  beq 1b
  movs r2, #1
  str r2, [r1, #8]
2: wfe
  b 2b
""", NMI_H=f"""  ldr r0, ={RES}
  ldr r1, =0x40023800
  ldr r2, [r1, #12]
  str r2, [r0]
  ldr r2, [r1, #8]
  str r2, [r0, #4]
  ldr r2, [r1]
  str r2, [r0, #8]
  mrs r2, ipsr
  str r2, [r0, #12]
  mov r2, #0x800000
  str r2, [r1, #12]
  bx lr""")
        m = self.sim(path)
        m.uc.mem_write(RES, bytes(16))
        m.fail_hse_at(0.001)
        m.run_until(0.01)
        cir, cfgr, cr, ipsr = self.words(m, 4)
        self.assertTrue(cir & (1 << 7))
        self.assertEqual(cfgr & 0xF, 0)
        self.assertFalse(cr & (1 << 17))
        self.assertEqual(ipsr, 2)
        self.assertEqual(m.exc_counts[emu.NMI], 1)  # CSSC in the handler: not taken again
        self.assertEqual(m.rcc.tree()["sysclk_source"], "HSI")

    def test_undefined_instruction_is_a_forced_hardfault(self):
        path = self.build("""  udf #0
1: b 1b
""", HardFault_H=HARDFAULT_SAVES_CFSR_HFSR + """1: wfe
  b 1b""")
        m = self.sim(path)
        m.run_until(0.001)
        cfsr, hfsr = self.words(m, 2)
        self.assertEqual(cfsr, emu.UNDEFINSTR)
        self.assertEqual(hfsr, emu.HFSR_FORCED)

    def test_instruction_fetch_fault_is_ibuserr(self):
        path = self.build("""  ldr r0, =0x60000001
  blx r0
1: b 1b
""", HardFault_H=HARDFAULT_SAVES_CFSR_HFSR + """  ldr r2, [sp, #24]
  str r2, [r0, #8]
1: wfe
  b 1b""")
        m = self.sim(path)
        m.run_until(0.001)
        cfsr, hfsr, pc = self.words(m, 3)
        self.assertEqual(cfsr, emu.IBUSERR)  # no BFARVALID for a fetch
        self.assertEqual(hfsr, emu.HFSR_FORCED)
        self.assertEqual(pc, 0x6000_0000)

    def test_fp_context_survives_a_handler(self):
        # the thread holds 1.5 in s0 across a SysTick whose handler overwrites s0: FPCA -> 26-word frame
        path = self.build(f"""  vmov.f32 s0, #1.5
{self.SYSTICK_ON}
  ldr r6, =20000
1: subs r6, #1
  bne 1b
  ldr r0, ={RES}
  vstr s0, [r0]
  mov r1, sp
  str r1, [r0, #8]
2: wfe
  b 2b
""", SysTick_H=f"""  vmov.f32 s0, #3.0
  ldr r0, ={RES}
  str lr, [r0, #4]
  bx lr""")
        m = self.sim(path)
        m.run_until(0.01)
        s0 = struct.unpack("<f", bytes(m.uc.mem_read(RES, 4)))[0]
        exc_ret, sp = self.words(m, 2, RES + 4)
        self.assertEqual(s0, 1.5)
        self.assertEqual(exc_ret, 0xFFFF_FFE9)
        self.assertEqual(sp, 0x2000_1000)


if __name__ == "__main__":
    unittest.main(verbosity=2)
