#!/usr/bin/env python3
"""Scenario mode of the F405 emulation: boot.py's chip plus exceptions, the watchdog, resets and fault models.

`boot.Machine` boots the ELF to the executor's first idle and, in `--frames` mode, delivers interrupts only at idle.
`Sim` (this module) runs the same ELF as a chip over many seconds of virtual time and across resets:

Exceptions (ARMv7-M, checked at translation-block boundaries)
    NMI (2), HardFault (3), MemManage/BusFault/UsageFault (4-6, only when enabled in SHCSR; otherwise escalated to
    HardFault with HFSR.FORCED), PendSV (14, ICSR), SysTick (15) and the IRQs (16+n, NVIC ISER/ISPR/STIR and the
    level-triggered peripheral sources of boot.py). Priorities from NVIC_IPR/SHPR (4 implemented bits), group
    priority by AIRCR.PRIGROUP, masking by PRIMASK/BASEPRI/FAULTMASK; a pending exception preempts thread code or a
    lower-priority handler (nesting), lowest priority value first, then lowest number. Entry: the 8-word frame
    (26 words with S0-S15/FPSCR when CONTROL.FPCA is set: unicorn tracks FPCA), 8-byte alignment with xPSR bit 9,
    EXC_RETURN 0xFFFFFFF1/F9/FD (E1/E9/ED with the FP frame), IPSR = the exception number (MRS IPSR sees it), the
    vector read through VTOR. Return: a branch to EXC_RETURN pops the frame from memory (a handler may edit it).
    Faults: an access to unmapped/protected memory -> BusFault (precise: CFSR.PRECISERR|BFARVALID, BFAR; instruction
    fetch: IBUSERR), an undefined instruction -> UsageFault UNDEFINSTR; escalated to HardFault (HFSR.FORCED) when the
    fault handler is disabled or cannot preempt. A frame that cannot be pushed (SP below SRAM) -> HardFault entered
    with SP as it was, CFSR.STKERR. A fault in HardFault or NMI -> lock-up (the core stops until the IWDG resets it).
    Not modelled: MemManage (no MPU), tail-chaining/late-arrival timing, lazy FP stacking as such (the FP registers
    are written at entry: what a handler sees is the same), PSP-based threads beyond the EXC_RETURN choice,
    imprecise bus faults (all precise), SVCall, DebugMonitor, the sleep-on-exit bit.
SysTick
    CSR/RVR/CVR/CALIB; counts down at HCLK (CLKSOURCE=1) or HCLK/8 (CLKSOURCE=0) of the modelled virtual time,
    COUNTFLAG (cleared by reading CSR), reload from RVR, the exception pended on each 1 -> 0 transition with TICKINT.
IWDG
    Started by 0xCCCC (counting down from 0xFFF, RM0090 21.3.1), reloaded from RLR by 0xAAAA, at LSI/(4 << PR)
    with LSI a parameter (`lsi_hz`, nominal 32 kHz); at 0 the core is reset. PR/RLR writable after 0x5555 only;
    SR.PVU/RVU always 0 (updates immediate). Not modelled: the hardware-watchdog option bit, the stop/standby freeze.
Resets
    IWDG, SYSRESETREQ (AIRCR), lock-up (none on the chip: only the IWDG ends it), power-on. A new boot from the
    reset vector: SRAM, CCM and backup SRAM (0x4002_4000, 4 KiB) and the RTC backup registers keep their contents;
    every other peripheral, the NVIC/SCB/SysTick and the core registers are back at their reset values; RCC_CSR's
    flags accumulate until RMVF: IWDG -> IWDGRSTF|PINRSTF, SYSRESETREQ -> SFTRSTF|PINRSTF (the chip pulses NRST
    for every internal reset), power-on -> PORRSTF|PINRSTF|BORRSTF. A cap on the number of resets ends the run.
Clock faults
    `hse_starts=False`: HSEON never brings HSERDY (a crystal that never starts). `hse_fail_at` (virtual s): the
    crystal stops; with CSSON the CSS sets CIR.CSSF, turns HSE off, switches SYSCLK to HSI (PLL off when HSE fed it)
    and pends the NMI (again after each NMI return while CSSF is set: CIR.CSSC clears it); without CSSON a core
    clocked from the HSE stops (only the IWDG, on the LSI, resets it).
USART receive errors
    `line_errors(usart, t0, t1, kinds)`: every byte received in [t0, t1) carries FE (or NE/PE); the byte is still
    transferred by the DMA when DMAR=1, otherwise it sets RXNE (ORE when RXNE was set). FE/NE/ORE raise the USART
    interrupt when CR3.EIE is set; the SR-then-DR read clears them (as embassy-stm32 0.6's ring-buffered RX sees it).
Flash (boot.py "Flash programming and erase")
    `flash_timing` ("max" | "typ") and `flash_bsy_polls`. The stall of an erase or program moves virtual time on
    for everything (timers, SysTick, the IWDG, timed stimuli, which are taken after it); an IWDG expiry during an
    erase resets the chip at the expiry, the erase cut short. Flash survives resets, RAM too. The code in flash is
    identified again at every reset and VTOR write (boot.ImageSet): the bootloader swaps an image in and jumps to it,
    the instruction tables, hot blocks and traps follow. fastblock's C code does the common flash accesses.

Time is virtual (instructions at the HCLK of the moment, 1 IPC; boot.py). At idle (WFE with no event) time jumps
to the next event: an FPGA frame, bus bytes, the end of a DMA transmission, a timer compare/overflow, SysTick, the
IWDG expiry, a clock failure. A loop of at most 6 blocks that touches no peripheral for 2M instructions, and then
again after each interrupt (a task spinning, a handler spinning) is fast-forwarded to the next event in the same
way (a busy delay loop that long would be timed wrongly: none exists in the firmware). The host-time slices of a
run end at a block's start, from the block hook (unicorn's emu_start timeout, which stops inside an instruction that
then runs again with its MMIO or flash side effects repeated, is only a backstop).
"""

from __future__ import annotations

import collections
import ctypes
import math
import struct
import time

import unicorn
from unicorn import UcError
from unicorn.arm_const import (UC_ARM_REG_BASEPRI, UC_ARM_REG_CONTROL, UC_ARM_REG_FAULTMASK, UC_ARM_REG_FPSCR,
                               UC_ARM_REG_IPSR, UC_ARM_REG_LR, UC_ARM_REG_MSP, UC_ARM_REG_PC, UC_ARM_REG_PRIMASK,
                               UC_ARM_REG_PSP, UC_ARM_REG_SP, UC_ARM_REG_XPSR)
import unicorn.unicorn_const as ucc

import boot
import fastblock
from boot import PERIPHERALS, SRAM_BASE, SRAM_SIZE

A = unicorn.arm_const
CORE_REGS = [A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3, A.UC_ARM_REG_R12, UC_ARM_REG_LR]
ALL_GPR = [getattr(A, f"UC_ARM_REG_R{i}") for i in range(13)]
S_REGS = [getattr(A, f"UC_ARM_REG_S{i}") for i in range(16)]

NMI, HARDFAULT, MEMMANAGE, BUSFAULT, USAGEFAULT, SVCALL, PENDSV, SYSTICK = 2, 3, 4, 5, 6, 11, 14, 15
EXC_NAMES = {NMI: "NMI", HARDFAULT: "HardFault", MEMMANAGE: "MemManage", BUSFAULT: "BusFault",
             USAGEFAULT: "UsageFault", SVCALL: "SVCall", PENDSV: "PendSV", SYSTICK: "SysTick"}

# RCC_CSR reset flags (RM0090 7.3.21)
RMVF, BORRSTF, PINRSTF, PORRSTF, SFTRSTF, IWDGRSTF, WWDGRSTF, LPWRRSTF = (1 << b for b in range(24, 32))
RESET_FLAGS = {"power-on": PORRSTF | PINRSTF | BORRSTF, "iwdg": IWDGRSTF | PINRSTF, "software": SFTRSTF | PINRSTF,
               "pin": PINRSTF, "lockup": 0}
# CFSR bits
IBUSERR, PRECISERR, STKERR, BFARVALID = 1 << 8, 1 << 9, 1 << 12, 1 << 15
UNDEFINSTR, INVSTATE = 1 << 16, 1 << 17
HFSR_FORCED, HFSR_VECTTBL = 1 << 30, 1 << 1
# USART SR bits
PE, FE, NE, ORE, IDLE, RXNE = 1, 2, 4, 8, 16, 32


def exc_name(n: int) -> str:
    return EXC_NAMES.get(n) or (f"IRQ {n - 16} ({boot.IRQ_NAMES.get(n - 16, '?')})" if n >= 16 else f"exception {n}")


# ---------------------------------------------------------------------------------------------------------------
# Peripheral models (subclasses of boot.py's register files)
# ---------------------------------------------------------------------------------------------------------------

class Timer(boot.Timer):
    def clock(self) -> float:
        t = self.m.tree()
        return t["tim_apb1"] if self.name in boot.TIMERS_APB1 else t["tim_apb2"]


class Iwdg(boot.Iwdg):
    """The counting watchdog: see the module docstring."""

    def __init__(self, *a):
        super().__init__(*a)
        self.running = False
        self.t_load, self.load, self.div = 0.0, 0xFFF, 4

    def _reload(self, value):
        self.t_load, self.load = self.m.now(), value
        self.div = 4 << min(self.regs.get(self.PR, 0) & 7, 6)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off == self.KR:
            key = value & 0xFFFF
            if key == 0xCCCC and not self.running:
                self.running = True
                self._reload(0xFFF)
            elif key == 0xAAAA and self.running:
                self._reload(self.regs.get(self.RLR, 0xFFF) & 0xFFF)
            elif key == 0xAAAA:
                self._reload(self.regs.get(self.RLR, 0xFFF) & 0xFFF)
        super().write_word(off, value, mask)

    def counter(self) -> int:
        if not self.running:
            return self.load
        ticks = int((self.m.now() - self.t_load) * self.m.lsi_hz / self.div)
        return max(self.load - ticks, 0)

    def expiry(self) -> float:
        """Virtual time at which the counter reaches 0 (inf when stopped)."""
        if not self.running:
            return math.inf
        return self.t_load + (self.load + 1) * self.div / self.m.lsi_hz


class Rcc(boot.Rcc):
    """boot.Rcc plus a crystal that may never start or may fail, and the clock security system."""
    CIR = 0x0C

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off == self.CIR:
            cir = self.regs.get(self.CIR, 0)
            if value & (1 << 23):  # CSSC
                cir &= ~(1 << 7)
            self.regs[self.CIR] = (cir & 0xFF) | (value & 0x3F00)  # flags read-only, enables RW, clears self-clear
            return
        super().write_word(off, value, mask)
        if off == self.CR:
            cr = self.regs[self.CR]
            if not self.m.hse_ok():
                self.regs[self.CR] = cr & ~(1 << 17)  # HSERDY never comes
                if self.regs[self.CR] & (1 << 24) and self.regs[self.PLLCFGR] & (1 << 22):
                    self.regs[self.CR] &= ~(1 << 25)  # a PLL fed by a dead crystal never locks

    def _ready(self, sw):
        if sw == 2 and self.regs[self.PLLCFGR] & (1 << 22) and not self.m.hse_ok():
            return False
        return super()._ready(sw)

    def hse_failure(self):
        """The crystal stops now."""
        cr, cfgr = self.regs[self.CR], self.regs.get(self.CFGR, 0)
        if not cr & (1 << 17):
            return "HSE was not running"
        sws = (cfgr >> 2) & 3
        pll_hse = bool(self.regs[self.PLLCFGR] & (1 << 22))
        cr &= ~(1 << 17)
        if cr & (1 << 19):  # CSSON: CSS detects it
            cr &= ~(1 << 16)  # HSE off (the detector stops with it; CSSON keeps its value)
            if sws == 1 or (sws == 2 and pll_hse):
                cfgr = cfgr & ~0xF  # SW = SWS = HSI
                if pll_hse:
                    cr &= ~((1 << 24) | (1 << 25))
            elif pll_hse:
                cr &= ~((1 << 24) | (1 << 25))
            self.regs[self.CR] = cr
            self.regs[self.CFGR] = cfgr
            self.regs[self.CIR] = self.regs.get(self.CIR, 0) | (1 << 7)  # CSSF
            self.m.clock_changed()
            self.m.pend_exception(NMI)
            self.m.event("css", "HSE failed: CSS -> CSSF, SYSCLK HSI, NMI")
            return "css"
        self.regs[self.CR] = cr
        if sws == 1 or (sws == 2 and pll_hse):
            self.m.event("hse_fail", "HSE failed with CSS off: the core clock stops")
            return "halt"
        return "hse-off"


class Usart(boot.Usart):
    """boot.Usart plus received bytes with line errors (FE/NE/PE), RXNE/ORE and the error interrupt."""

    def __init__(self, *a):
        super().__init__(*a)
        self.err = 0  # FE|NE|PE|ORE|RXNE flags raised by reception
        self.seen = 0  # flags seen by an SR read (the SR-then-DR sequence clears them)
        self.rx_dr = 0
        self.rx_lost = 0

    def read_word(self, off):
        if off == self.SR:
            v = super().read_word(off) | self.err
            self.seen = self.err | (IDLE if self.idle else 0)
            return v
        if off == self.DR:
            self.idle = False
            self.err &= ~(self.seen & (FE | NE | PE | ORE))
            self.err &= ~RXNE
            self.seen = 0
            return self.rx_dr
        return super().read_word(off)

    def irq_pending(self) -> bool:
        cr1, cr3 = self.regs.get(self.CR1, 0), self.regs.get(self.CR3, 0)
        return bool(super().irq_pending() or (cr3 & 1 and self.err & (FE | NE | ORE))
                    or (cr1 & 0x100 and self.err & PE) or (cr1 & 0x20 and self.err & (RXNE | ORE)))

    def bytes_in(self, dma, stream, data: bytes, error: int = 0) -> None:
        """Received bytes, all with the same `error` flags (see byte_in)."""
        cr1, cr3 = self.regs.get(self.CR1, 0), self.regs.get(self.CR3, 0)
        if data and cr1 & (1 << 13) and cr1 & 4 and cr3 & 0x40 and dma is not None:
            s = dma.stream(stream)
            if s["en"] and stream in dma.ring_len:
                self.err |= error
                dma.receive(stream, data)
                return
        for b in data:
            self.byte_in(dma, stream, b, error)

    def byte_in(self, dma, stream, byte: int, error: int = 0) -> None:
        """One received byte (with `error` flags): to the DMA ring when DMAR=1 and the stream runs, else to DR."""
        cr1, cr3 = self.regs.get(self.CR1, 0), self.regs.get(self.CR3, 0)
        if not (cr1 & (1 << 13) and cr1 & 4):  # UE, RE
            self.rx_lost += 1
            return
        self.err |= error
        s = dma.stream(stream) if dma is not None else None
        if cr3 & 0x40 and s and s["en"] and stream in dma.ring_len:
            dma.receive(stream, bytes([byte]))
            return
        self.rx_lost += 1
        if self.err & RXNE:
            self.err |= ORE
        else:
            self.err |= RXNE
            self.rx_dr = byte


class Dma(boot.Dma):
    """boot.Dma with the F4's stream restart (AN4031 §4.2 / RM0090 10.3.17): disabling a stream mid-transfer sets
    TCIF and keeps NDTR; enabling it again restarts at M0AR with NDTR as it is, and the circular reload brings back
    the NDTR last programmed while disabled. Received bytes are written in contiguous runs."""

    def __init__(self, *a):
        super().__init__(*a)
        self.prog, self.off = {}, {}

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off >= 0x10 and (off - 0x10) % 0x18 == 4:  # NDTR: writable while the stream is disabled
            n = (off - 0x10) // 0x18
            if not self.regs.get(off - 4, 0) & 1:
                self.prog[n] = value & 0xFFFF
        if off >= 0x10 and (off - 0x10) % 0x18 == 0:
            n, old = (off - 0x10) // 0x18, self.regs.get(off, 0)
            b = off
            if old & 1 and not value & 1 and self.regs.get(b + 4, 0) and not getattr(
                    self.m, "dma_no_tcif_on_disable", False):  # disabled mid-transfer (what-if: no TCIF)
                self.set_flag(n, 5)
                self.m.poke()
            if value & 1 and not old & 1:
                super().write_word(off, value, mask)
                s = self.stream(n)
                if s["dir"] == "P2M" and s["circ"]:
                    prog = self.prog.get(n) or s["ndtr"]
                    self.ring_len[n] = prog
                    # the chip restarts at M0AR; `dma_resume_in_place` (a what-if, not the F4) keeps the position
                    resumed = getattr(self.m, "dma_resume_in_place", False) and self.regs.get(b + 4, 0)
                    self.off[n] = (prog - self.regs.get(b + 4, 0)) % prog if resumed else 0
                    if not self.regs.get(b + 4, 0):
                        self.regs[b + 4] = prog
                return
        super().write_word(off, value, mask)

    def receive(self, n, data: bytes):
        b = 0x10 + 0x18 * n
        length, base = self.ring_len[n], self.regs.get(b + 0xC, 0)
        i = 0
        while i < len(data):
            ndtr = self.regs.get(b + 4, 0) or length
            pos = self.off.get(n, length - ndtr)
            run = min(len(data) - i, ndtr, length - pos)
            self.m.uc.mem_write(base + pos, bytes(data[i:i + run]))
            half = length // 2
            if ndtr > half >= ndtr - run:
                self.set_flag(n, 4)
            ndtr -= run
            pos += run
            i += run
            if ndtr == 0 or pos >= length:
                if ndtr == 0:
                    self.set_flag(n, 5)
                ndtr, pos = (length, 0) if ndtr == 0 else (ndtr, 0)
            self.regs[b + 4] = ndtr
            self.off[n] = pos


class Ppb(boot.Ppb):
    """boot.Ppb plus SysTick, ICSR, SHCSR, the fault status registers and AIRCR.SYSRESETREQ as a reset."""
    ICSR, VTOR, SHPR1, SHPR2, SHPR3, SHCSR, CFSR, HFSR, MMFAR, BFAR = (0xED04, 0xED08, 0xED18, 0xED1C, 0xED20,
                                                                      0xED24, 0xED28, 0xED2C, 0xED34, 0xED38)
    ST_CSR, ST_RVR, ST_CVR, ST_CALIB = 0xE010, 0xE014, 0xE018, 0xE01C

    def __init__(self, *a):
        super().__init__(*a)
        self.st_t0, self.st_c0, self.st_zeros_seen = 0.0, 0, 0

    # -- SysTick -----------------------------------------------------------------------------------------------
    def st_hz(self) -> float:
        return self.m.hz if self.regs.get(self.ST_CSR, 0) & 4 else self.m.hz / 8

    def _st_ticks(self) -> int:
        return int((self.m.now() - self.st_t0) * self.st_hz() + 1e-9)

    def _st_first_zero(self) -> int:
        rvr = self.regs.get(self.ST_RVR, 0) & 0xFF_FFFF
        return self.st_c0 if self.st_c0 else rvr + 1

    def _st_zeros(self, ticks) -> int:
        rvr = self.regs.get(self.ST_RVR, 0) & 0xFF_FFFF
        z1 = self._st_first_zero()
        if rvr == 0 and self.st_c0 == 0:
            return 0
        if ticks < z1:
            return 0
        return 1 + ((ticks - z1) // (rvr + 1) if rvr else 0)

    def st_value(self) -> int:
        csr = self.regs.get(self.ST_CSR, 0)
        if not csr & 1:
            return self.st_c0
        rvr = self.regs.get(self.ST_RVR, 0) & 0xFF_FFFF
        t = self._st_ticks()
        z1 = self._st_first_zero()
        if t < z1:
            return self.st_c0 - t if self.st_c0 else (rvr - (t - 1) if t else 0)
        phase = (t - z1) % (rvr + 1)
        return 0 if phase == 0 else rvr + 1 - phase

    def st_rebase(self):
        """Before the counter's clock or configuration changes."""
        self.st_update()
        self.st_c0, self.st_t0, self.st_zeros_seen = self.st_value(), self.m.now(), 0

    def st_update(self):
        """COUNTFLAG and the SysTick exception for the 1 -> 0 transitions since the last look."""
        csr = self.regs.get(self.ST_CSR, 0)
        if not csr & 1:
            return
        z = self._st_zeros(self._st_ticks())
        if z > self.st_zeros_seen:
            self.st_zeros_seen = z
            self.regs[self.ST_CSR] = csr | (1 << 16)
            if csr & 2:
                self.m.pend_exception(SYSTICK)

    def st_next_event(self) -> float:
        csr = self.regs.get(self.ST_CSR, 0)
        if not (csr & 1 and csr & 2):
            return math.inf
        rvr = self.regs.get(self.ST_RVR, 0) & 0xFF_FFFF
        z1 = self._st_first_zero()
        if rvr == 0 and self.st_c0 == 0:
            return math.inf
        n = self.st_zeros_seen
        tick = z1 + n * (rvr + 1)
        return self.st_t0 + tick / self.st_hz()

    # -- registers ---------------------------------------------------------------------------------------------
    def read_word(self, off):
        if off == self.ST_CSR:
            self.st_update()
            v = self.regs.get(off, 0)
            self.regs[off] = v & ~(1 << 16)
            return v
        if off == self.ST_CVR:
            self.st_update()
            return self.st_value()
        if off == self.ICSR:
            v = self.regs.get(off, 0) & 0
            act = self.m.active[-1] if self.m.active else 0
            v |= act & 0x1FF
            pend = self.m.best_pending(ignore_mask=True)
            if pend:
                v |= (pend[1] & 0x1FF) << 12
            v |= (1 << 31) if NMI in self.m.sys_pending else 0
            v |= (1 << 28) if PENDSV in self.m.sys_pending else 0
            v |= (1 << 26) if SYSTICK in self.m.sys_pending else 0
            if len(self.m.active) <= 1:
                v |= 1 << 11  # RETTOBASE
            return v
        return super().read_word(off)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        m = self.m
        m.poke()
        if off == self.ST_CSR:
            self.st_rebase()
            self.regs[off] = (value & 7) | (self.regs.get(off, 0) & (1 << 16))
            self.st_t0 = m.now()
            return
        if off == self.ST_RVR:
            self.st_rebase()
            self.regs[off] = value & 0xFF_FFFF
            return
        if off == self.ST_CVR:  # any write clears the counter and COUNTFLAG
            self.st_c0, self.st_t0, self.st_zeros_seen = 0, m.now(), 0
            self.regs[self.ST_CSR] = self.regs.get(self.ST_CSR, 0) & ~(1 << 16)
            return
        if off == self.ICSR:
            for bit, exc in ((31, NMI), (28, PENDSV), (26, SYSTICK)):
                if value & (1 << bit):
                    m.pend_exception(exc)
            if value & (1 << 27):
                m.sys_pending.discard(PENDSV)
            if value & (1 << 25):
                m.sys_pending.discard(SYSTICK)
            return
        if off in (self.CFSR, self.HFSR):  # write 1 to clear
            self.regs[off] = self.regs.get(off, 0) & ~value
            return
        if off == self.AIRCR:
            if value >> 16 == 0x05FA:
                self.regs[off] = value & 0x700
                if value & 0x4:
                    m.request_reset("software", "SCB AIRCR SYSRESETREQ")
            else:
                m.warn("SCB_AIRCR written without VECTKEY 0x05FA (ignored by hardware)")
            return
        super().write_word(off, value, mask)

    def sys_priority(self, exc: int) -> int:
        reg = 0xED18 + ((exc - 4) & ~3)
        return (self.regs.get(reg, 0) >> (8 * ((exc - 4) & 3))) & 0xF0


class BackupSram(boot.Periph):
    """The 4 KiB backup SRAM: contents survive every reset (battery-backed domain)."""


# ---------------------------------------------------------------------------------------------------------------
# The machine
# ---------------------------------------------------------------------------------------------------------------

class Sim(boot.Machine):
    """The chip over time and across resets (see the module docstring)."""

    KEEP_ACROSS_RESET = ("BKPSRAM", "RTC/BKP")

    # the hook's counters live in a C struct (fastblock.State) shared with the C block hook
    insns = property(lambda self: self._st.insns, lambda self, v: setattr(self._st, "insns", v))
    next_check = property(lambda self: self._st.next_check, lambda self, v: setattr(self._st, "next_check", max(v, 0)))
    win_start = property(lambda self: self._st.win_start, lambda self, v: setattr(self._st, "win_start", max(v, 0)))
    last_block = property(lambda self: (self._st.last_addr, self._st.last_size),
                          lambda self, v: (setattr(self._st, "last_addr", v[0] & 0xFFFF_FFFF),
                                           setattr(self._st, "last_size", v[1])))
    # virtual time and the MMIO count live there too: the C flash path stalls the clock and counts accesses
    t_base = property(lambda self: self._st.t_base, lambda self, v: setattr(self._st, "t_base", v))
    hz = property(lambda self: self._st.hz, lambda self, v: setattr(self._st, "hz", v))
    mmio_count = property(lambda self: self._st.mmio_count, lambda self, v: setattr(self._st, "mmio_count", v))

    def __init__(self, img, args, *, lsi_hz: float = 32_000.0, hse_starts: bool = True,
                 max_resets: int = 10, spin_window: int = 50_000, spin_windows: int = 40,
                 flash_timing: str | None = None, flash_bsy_polls: int | None = None):
        self._st = fastblock.State()
        self._st.spin_window = spin_window
        self.ninsn = {}
        self._build_tables(img)
        if flash_timing is not None:
            args.flash_timing = flash_timing
        if flash_bsy_polls is not None:
            args.flash_bsy_polls = flash_bsy_polls
        self.lsi_hz = lsi_hz
        self.hse_starts, self.hse_dead = hse_starts, False
        self.max_resets = max_resets
        self.spin_window, self.spin_windows = spin_window, spin_windows
        self.active, self.sys_pending = [], set()
        self.halted = None  # "lockup" | "clock" while the core executes nothing
        self.boots = []  # per boot: dict(t, cause, flags, insn)
        self.req = None  # why the current emu_start was stopped: "preempt" | "reset" | "fault"
        self.fault = None
        self.reset_req = None
        self.timed = []  # (t, seq, callback)
        self._seq = 0
        self.next_check = 0
        self.win_mmio = 0
        self.known_spins, self.spin_seen, self.spins_skipped = [], collections.Counter(), 0
        self.mmio_count = 0
        self.exc_log = []
        self.usart_errors = []  # (usart name, t0, t1, flags)
        self.bus_tx = bytearray()
        self.rx_feed_log = []
        self.exc_counts = collections.Counter()
        self.c_hook = False
        self.c_flash = False
        super().__init__(img, args)
        self._st.f_bsy_polls = self.flash_bsy_polls
        self._st.f_prog_s = boot.FLASH_PROGRAM_S[self.flash_timing]
        self.boots.append({"t": 0.0, "cause": "power-on", "csr_flags": RESET_FLAGS["power-on"], "insn": 0})
        self.handler_hits = collections.Counter()
        self._mark_hot()

    def _build_tables(self, img):
        """fastblock's instruction-start and hot tables over the flash code of the ELF(s) in flash."""
        known = getattr(img, "known", [img])
        ends = [max(im.insn_sorted) + 8 for im in known if im.insn_sorted]
        text_end = max(ends) if ends else boot.FLASH_BASE
        self._idx, self._hot, self._len_hw = fastblock.tables(img, boot.FLASH_BASE, text_end - boot.FLASH_BASE)
        self._st.idx = ctypes.cast(self._idx, ctypes.POINTER(ctypes.c_uint32))
        self._st.hot = ctypes.cast(self._hot, ctypes.POINTER(ctypes.c_uint8))
        self._st.base, self._st.len_hw = boot.FLASH_BASE, self._len_hw
        self.ninsn.clear()

    def _mark_hot(self):
        # reaching the panic/fault handlers is no stop here: they record and reset, which is the point
        self.trap_names, self.trap = self.trap, {}
        self.hot = set(self.trap_names) | set(self.special) | set(self.img.task_polls)
        for a in self.hot:
            h = (a - boot.FLASH_BASE) // 2
            if 0 <= h < self._len_hw:
                self._hot[h] = 1

    def _images_changed(self):
        """Other code in flash (the bootloader swapped an image in and jumps to it): new tables and hooks."""
        self._build_tables(self.img)
        self.polled.clear()  # task polls count from when their code is in flash
        super()._images_changed()
        self._mark_hot()

    def _install_hooks(self):
        """boot.py's hooks, with the block hook registered through a bare ctypes callback (one Python layer less
        per block than unicorn's wrapper: the block hook is most of a run's host time)."""
        uc = self.uc
        real_add = uc.hook_add

        def add(htype, cb, *a, **k):
            if htype != unicorn.UC_HOOK_BLOCK:
                return real_add(htype, cb, *a, **k)
            lib = fastblock.library()
            if lib is not None:
                self._c_cb = fastblock.PY_CB(self._c_callback)
                self._st.cb = self._c_cb
                from unicorn.unicorn_py3.unicorn import uclib, uc_hook_h
                handle = uc_hook_h()
                status = uclib.uc_hook_add(uc._uch, ctypes.byref(handle), unicorn.UC_HOOK_BLOCK,
                                           ctypes.cast(lib.fw_block, ctypes.c_void_p),
                                           ctypes.cast(ctypes.pointer(self._st), ctypes.c_void_p),
                                           ctypes.c_uint64(1), ctypes.c_uint64(0))
                if status == 0:
                    self.c_hook = True
                    uc._callbacks[handle.value] = (self._c_cb, lib)
                    return handle.value
            on_block = self._on_block

            def raw(handle, addr, size, key):
                try:
                    on_block(uc, addr, size, None)
                except BaseException as e:  # noqa: BLE001 (recorded, re-raised after emu_start)
                    if uc._hook_exception is None:
                        uc._hook_exception = e
                    uc.emu_stop()
            from unicorn.unicorn_py3.unicorn import HOOK_CODE_CFUNC
            fptr = HOOK_CODE_CFUNC(raw)
            return uc._Uc__do_hook_add(htype, fptr, 1, 0)
        uc.hook_add = add
        try:
            super()._install_hooks()
        finally:
            del uc.hook_add

    # -- models ------------------------------------------------------------------------------------------------
    def hse_ok(self) -> bool:
        return self.hse_starts and not self.hse_dead

    def _map_peripherals(self):
        kinds = {"RCC": Rcc, "PWR": boot.Pwr, "USART1": Usart, "USART2": Usart,
                 "FLASH": lambda m, n, b: boot.FlashIf(m, n, b, regs=m._st),
                 "USART3": Usart, "USART6": Usart, "DMA1": Dma, "DMA2": Dma, "IWDG": Iwdg,
                 "ADC": boot.Adc, "BKPSRAM": BackupSram}
        old = getattr(self, "blocks", None)
        self.blocks = {}
        for name, base in PERIPHERALS.items():
            if old is not None and name in self.KEEP_ACROSS_RESET:
                self.blocks[base] = old[base]
                continue
            cls = kinds.get(name) or (Timer if name in boot.TIMERS_APB1 | boot.TIMERS_APB2 else
                                      boot.Gpio if name.startswith("GPIO") else boot.Periph)
            self.blocks[base] = cls(self, name, base)
        self.rcc, self.flash = self.blocks[PERIPHERALS["RCC"]], self.blocks[PERIPHERALS["FLASH"]]
        self.ppb = Ppb(self, "PPB", boot.PPB_BASE)
        self.block_starts = sorted(self.blocks)
        if old is None:
            self._map_windows()
        self._sources = self.irq_sources() if old is not None else []

    def block(self, name):
        return self.blocks[PERIPHERALS[name]]

    _tree_key, _tree = None, None

    def tree(self) -> dict:
        """The clock tree (cached on the three RCC registers it depends on)."""
        r = self.rcc.regs
        key = (r[Rcc.CR], r[Rcc.PLLCFGR], r.get(Rcc.CFGR, 0))
        if key != self._tree_key:
            self._tree_key, self._tree = key, boot.clock_tree(*key)
        return self._tree

    def clock_changed(self):
        ppb = getattr(self, "ppb", None)
        if ppb is not None:
            ppb.st_rebase()
        super().clock_changed()
        if ppb is not None:
            ppb.st_t0 = self.now()

    def poke(self):
        """Something changed that may pend an exception: look at the next block boundary."""
        self.next_check = 0

    def _periph_write(self, uc, off, size, value, window):
        self.mmio_count += 1
        self.next_check = 0
        super()._periph_write(uc, off, size, value, window)

    def _periph_read(self, uc, off, size, window):
        self.mmio_count += 1
        return super()._periph_read(uc, off, size, window)

    def _ppb_read(self, uc, off, size, _):
        self.mmio_count += 1
        return super()._ppb_read(uc, off, size, _)

    # -- flash: fastblock's C paths when the library is there, else boot.Machine's Python ones ------------------
    def _map_windows(self):
        lib = fastblock.library()
        if lib is None or self.args.trace_mmio:
            return super()._map_windows()
        from unicorn.unicorn_py3.unicorn import uclib
        fl = PERIPHERALS["FLASH"]
        for base, size in boot.PERIPH_WINDOWS:
            if base <= fl < base + size:
                self.uc.mmio_map(base, fl - base, self._periph_read, base, self._periph_write, base)
                st = ctypes.cast(ctypes.pointer(self._st), ctypes.c_void_p)
                status = uclib.uc_mmio_map(self.uc._uch, fl, 0x400, ctypes.cast(lib.fw_flash_read, ctypes.c_void_p),
                                           st, ctypes.cast(lib.fw_flash_write, ctypes.c_void_p), st)
                if status != 0:
                    raise UcError(status)
                rest = fl + 0x400
                self.uc.mmio_map(rest, base + size - rest, self._periph_read, rest, self._periph_write, rest)
            else:
                self.uc.mmio_map(base, size, self._periph_read, base, self._periph_write, base)
        self.uc.mmio_map(boot.PPB_BASE, boot.PPB_SIZE, self._ppb_read, None, self._ppb_write, None)
        self.c_flash = True

    def _flash_store_hook(self):
        self._st.mem = ctypes.cast(self.flash_buf, ctypes.POINTER(ctypes.c_uint8))
        self._flash_cb_ref = fastblock.FLASH_CB(self._flash_cb)
        self._st.fcb = self._flash_cb_ref
        lib = fastblock.library()
        if lib is None or self.args.trace_mmio:
            return super()._flash_store_hook()
        from unicorn.unicorn_py3.unicorn import uclib, uc_hook_h
        handle = uc_hook_h()
        status = uclib.uc_hook_add(self.uc._uch, ctypes.byref(handle), unicorn.UC_HOOK_MEM_WRITE,
                                   ctypes.cast(lib.fw_flash_store, ctypes.c_void_p),
                                   ctypes.cast(ctypes.pointer(self._st), ctypes.c_void_p),
                                   ctypes.c_uint64(0), ctypes.c_uint64(boot.FLASH_BASE + boot.FLASH_SIZE - 1))
        if status != 0:
            raise UcError(status)
        self.uc._callbacks[handle.value] = (self._flash_cb_ref, lib)

    def _flash_cb(self, kind, off, size, value):
        """fastblock's flash paths hand the uncommon accesses to the model (boot.FlashIf) here."""
        try:
            if kind == 0:
                v = super()._flash_read(self.uc, off, size, None)
            elif kind == 1:
                super()._flash_write(self.uc, off, size, value, None)
                v = 0
                if self.flash.s.f_cr & (boot.FlashIf.EOPIE | boot.FlashIf.ERRIE):
                    self.next_check = 0
            else:
                old = int.from_bytes(self.flash_mem[off:off + size], "little")
                v = self.flash.program(off, size, value, old)
            if not self.args.trace_mmio:
                self._st.f_fast = 1  # the first access is recorded (touched): the C paths take the common ones
            return v
        except BaseException as e:  # noqa: BLE001 (re-raised after emu_start)
            if self.uc._hook_exception is None:
                self.uc._hook_exception = e
            self.uc.emu_stop()
            return value

    def _flash_read(self, uc, off, size, _):
        self.mmio_count += 1
        return super()._flash_read(uc, off, size, _)

    def _flash_write(self, uc, off, size, value, _):
        self.mmio_count += 1
        super()._flash_write(uc, off, size, value, _)
        if self.flash.s.f_cr & (boot.FlashIf.EOPIE | boot.FlashIf.ERRIE):
            self.next_check = 0

    def _on_flash_write(self, uc, access, addr, size, value, _):
        self.mmio_count += 1  # a program loop is no spin
        return super()._on_flash_write(uc, access, addr, size, value, _)

    def flash_sync(self):
        st = self._st
        if st.fix_pending:
            st.fix_pending = 0
            self.flash_mem[st.fix_off:st.fix_off + st.fix_size] = st.fix_val.to_bytes(8, "little")[:st.fix_size]
        super().flash_sync()

    def flash_summary(self) -> dict:
        """boot.Machine.flash_summary with the C path's counts added."""
        out = super().flash_summary()
        st = self._st
        out["programs"] += st.f_programs
        out["bytes_programmed"] += st.f_bytes
        out["unlocks"] += st.f_unlocks
        out["program_s"] = round(out["program_s"] + st.f_program_s, 6)
        return out

    def flash_stall(self, seconds: float, erase: bool = False) -> float:
        """The CPU stalls for `seconds` (boot.Machine.flash_stall). If the IWDG expires during an erase, the reset
        comes at its expiry: the time that passed is returned (the erase is cut short). Events that fall due are
        taken at the next block boundary: the pending check moves closer by the stall (its distance is counted in
        cycles)."""
        if erase:
            t0 = self.now()
            expiry = self.block("IWDG").expiry()
            if expiry < t0 + seconds:
                seconds = max(expiry - t0, 0.0)
            self.skip_time(seconds)
            self.next_check = 0
            return seconds
        self.skip_time(seconds)
        st = self._st
        st.next_check = max(st.next_check - int(seconds * self.hz), 0)
        return seconds

    def _on_wfi(self, uc, addr, size, _):
        pass  # WFI is an idle like WFE without an event (handled where unicorn stops on it)

    def _spin_check(self, key, p):
        pass  # a busy-wait on a register is a spin the watchdog ends here (fast-forwarded like any other)

    def stop(self, kind, msg):
        """boot.py's stop: in scenario mode a fault found in an MMIO callback is a (late) BusFault."""
        if kind == "fault" and self.fault is None and self.stop_kind is None:
            self.fault = {"kind": "bus", "addr": None, "msg": msg, "precise": False}
            self.req = "fault"
            self.uc.emu_stop()
            return
        super().stop(kind, msg)

    # -- exceptions --------------------------------------------------------------------------------------------
    def pend_exception(self, exc: int):
        if exc >= 16:
            n = exc - 16
            self.ppb.pending[n >> 5] |= 1 << (n & 31)
        else:
            self.sys_pending.add(exc)
        self.next_check = 0

    def priority(self, exc: int) -> int:
        if exc == NMI:
            return -2
        if exc == HARDFAULT:
            return -1
        if exc >= 16:
            return self.ppb.irq_priority(exc - 16) & 0xF0
        return self.ppb.sys_priority(exc)

    def group(self, prio: int) -> int:
        if prio < 0:
            return prio
        prigroup = (self.ppb.regs.get(self.ppb.AIRCR, 0) >> 8) & 7
        return prio & ~((2 << prigroup) - 1) & 0xFF

    def exec_priority(self) -> int:
        uc = self.uc
        p = 256
        for e in self.active:
            p = min(p, self.group(self.priority(e)))
        if uc.reg_read(UC_ARM_REG_FAULTMASK) & 1:
            p = min(p, -1)
        if uc.reg_read(UC_ARM_REG_PRIMASK) & 1:
            p = min(p, 0)
        bp = uc.reg_read(UC_ARM_REG_BASEPRI) & 0xF0
        if bp:
            p = min(p, self.group(bp))
        return p

    def best_pending(self, ignore_mask=False):
        """(priority, exception) of the pending exception that would be taken next, or None."""
        irqs = self.pending_irqs()
        cands = [(self.group(self.priority(e)), e) for e in self.sys_pending]
        cands += [(self.group(self.priority(16 + irq)), 16 + irq) for irq in irqs]
        self._masked_pending = False
        if not cands:
            return None
        best = min(cands)
        if ignore_mask:
            return best
        if best[0] < self.exec_priority():
            return best
        self._masked_pending = True
        return None

    _masked_pending = False

    def pending_irqs(self):
        """Enabled IRQs pending: software-pended (ISPR/STIR) or raised by a modelled peripheral."""
        ppb = self.ppb
        ppb.st_update()
        en = ppb.enabled
        pend = set()
        for irq, p, n in self._sources:
            if not en[irq >> 5] >> (irq & 31) & 1:
                continue
            if isinstance(p, boot.Timer):
                p.update_flags()
            if p.irq_pending(n) if n is not None else p.irq_pending():
                pend.add(irq)
        for i in range(8):
            w = ppb.pending[i] & en[i]
            while w:
                b = (w & -w).bit_length() - 1
                pend.add(32 * i + b)
                w &= w - 1
        return sorted(pend)

    def enter_exception(self, exc: int, return_pc: int) -> bool:
        """Exception entry. False if the run ends (lock-up or a stop)."""
        uc, ppb = self.uc, self.ppb
        if exc >= 16:
            n = exc - 16
            ppb.pending[n >> 5] &= ~(1 << (n & 31))
        else:
            self.sys_pending.discard(exc)
        control = uc.reg_read(UC_ARM_REG_CONTROL)
        handler_mode = bool(self.active)
        use_psp = not handler_mode and control & 2
        fpca = bool(control & 4)
        sp = uc.reg_read(UC_ARM_REG_PSP if use_psp else UC_ARM_REG_MSP)
        words = 26 if fpca else 8
        xpsr = uc.reg_read(UC_ARM_REG_XPSR)
        ipsr = self.active[-1] if self.active else 0
        xpsr = (xpsr & ~0x1FF) | ipsr
        pad = 4 if sp & 4 else 0
        new_sp = sp - pad - 4 * words
        frame = [uc.reg_read(r) for r in CORE_REGS] + [return_pc & ~1, xpsr | (0x200 if pad else 0)]
        if fpca:
            frame += [uc.reg_read(r) for r in S_REGS] + [uc.reg_read(UC_ARM_REG_FPSCR), 0]
        data = struct.pack(f"<{words}I", *(v & 0xFFFF_FFFF for v in frame))
        stk_err = not (SRAM_BASE <= new_sp and sp <= SRAM_BASE + SRAM_SIZE) and not (
            boot.CCM_BASE <= new_sp and sp <= boot.CCM_BASE + boot.CCM_SIZE)
        if not stk_err:
            try:
                uc.mem_write(new_sp, data)
            except UcError:
                stk_err = True
        self.min_sp = min(self.min_sp, new_sp)
        if stk_err:
            # the frame cannot be pushed: on the M4 a BusFault on stacking (STKERR), escalated; the handler is
            # entered with SP as it was (a naked handler moves MSP first)
            if exc in (HARDFAULT, NMI) and handler_mode and HARDFAULT in self.active:
                return self.lockup(f"stacking for {exc_name(exc)} failed inside HardFault (SP=0x{sp:08x})")
            self.exc_log.append({"t": self.now(), "what": "stacking failed", "exc": exc_name(exc),
                                 "sp": sp})
            ppb.regs[ppb.CFSR] = ppb.regs.get(ppb.CFSR, 0) | STKERR
            if exc != HARDFAULT:
                ppb.regs[ppb.HFSR] = ppb.regs.get(ppb.HFSR, 0) | HFSR_FORCED
                if exc >= 16:  # the interrupt stays pending
                    self.pend_exception(exc)
                elif exc != NMI:
                    self.sys_pending.add(exc)
            exc, new_sp = HARDFAULT, sp
        else:
            uc.reg_write(UC_ARM_REG_PSP if use_psp else UC_ARM_REG_MSP, new_sp)
        vtor = ppb.regs.get(ppb.VTOR, 0) & ~0x7F
        try:
            handler = struct.unpack("<I", bytes(uc.mem_read(vtor + 4 * exc, 4)))[0]
        except UcError:
            handler = 0
        if not handler or handler == 0xFFFF_FFFF:
            return self.lockup(f"{exc_name(exc)}: no vector (VTOR 0x{vtor:08x})")
        exc_return = 0xFFFF_FFE1 if fpca else 0xFFFF_FFF1
        if not handler_mode:
            exc_return |= 0xC if use_psp else 0x8
        uc.reg_write(UC_ARM_REG_LR, exc_return)
        uc.reg_write(UC_ARM_REG_CONTROL, control & ~6)
        if use_psp:
            uc.reg_write(UC_ARM_REG_SP, uc.reg_read(UC_ARM_REG_MSP))
        uc.reg_write(UC_ARM_REG_IPSR, exc)
        uc.reg_write(UC_ARM_REG_XPSR, 0x0100_0000 | exc)
        uc.reg_write(UC_ARM_REG_IPSR, exc)
        self.active.append(exc)
        self.exc_counts[exc] += 1
        if exc >= 16:
            self.irq_counts[exc - 16] += 1
        self.pc_next = handler & ~1
        self.exc_depth = len(self.active)
        return True

    def exception_return(self, exc_return: int) -> bool:
        uc = self.uc
        if not self.active:
            return self.lockup(f"EXC_RETURN 0x{exc_return:08x} in thread mode")
        done = self.active.pop()
        fp = not exc_return & 0x10
        to_thread = bool(exc_return & 8)
        use_psp = bool(exc_return & 4)
        sp = uc.reg_read(UC_ARM_REG_MSP)
        if use_psp:
            sp = uc.reg_read(UC_ARM_REG_PSP)
        words = 26 if fp else 8
        try:
            frame = struct.unpack(f"<{words}I", bytes(uc.mem_read(sp, 4 * words)))
        except UcError:
            return self.lockup(f"unstacking at 0x{sp:08x} failed")
        for r, v in zip(CORE_REGS, frame[:6]):
            uc.reg_write(r, v)
        pc, xpsr = frame[6], frame[7]
        if fp:
            for r, v in zip(S_REGS, frame[8:24]):
                uc.reg_write(r, v)
            uc.reg_write(UC_ARM_REG_FPSCR, frame[24])
        new_sp = sp + 4 * words + (4 if xpsr & 0x200 else 0)
        uc.reg_write(UC_ARM_REG_PSP if use_psp else UC_ARM_REG_MSP, new_sp)
        control = uc.reg_read(UC_ARM_REG_CONTROL)
        control = (control & ~4) | (4 if fp else 0)
        control = (control & ~2) | (2 if use_psp and to_thread else 0)
        uc.reg_write(UC_ARM_REG_CONTROL, control)
        uc.reg_write(UC_ARM_REG_SP, new_sp)
        ipsr = self.active[-1] if self.active else 0
        uc.reg_write(UC_ARM_REG_XPSR, (xpsr & ~0x1FF & ~0x200) | ipsr)
        uc.reg_write(UC_ARM_REG_IPSR, ipsr)
        if done == NMI and self.rcc.regs.get(Rcc.CIR, 0) & (1 << 7):
            self.sys_pending.add(NMI)  # CSSF still set: the NMI is taken again
        self.exc_depth = len(self.active)
        self.event_flag = True  # an exception return is a WFE wake-up event (the executor polls again)
        self.pc_next = pc & ~1
        self._short_window_if_spin(self.pc_next)
        return True

    def raise_fault(self, kind: str, addr, pc: int, what: str) -> bool:
        """A synchronous fault at pc: BusFault/UsageFault if enabled and able to preempt, else HardFault."""
        ppb = self.ppb
        cfsr = ppb.regs.get(ppb.CFSR, 0)
        if kind == "bus":
            if what == "instruction fetch":
                cfsr |= IBUSERR
            else:
                cfsr |= PRECISERR
                if addr is not None:
                    cfsr |= BFARVALID
                    ppb.regs[ppb.BFAR] = addr & 0xFFFF_FFFF
            target, ena = BUSFAULT, 1 << 17
        else:
            cfsr |= UNDEFINSTR
            target, ena = USAGEFAULT, 1 << 18
        ppb.regs[ppb.CFSR] = cfsr
        self.exc_log.append({"t": self.now(), "what": f"{kind} fault", "pc": pc, "addr": addr, "access": what,
                             "active": [exc_name(e) for e in self.active]})
        if any(e in (HARDFAULT, NMI) for e in self.active) and (
                self.active[-1] == HARDFAULT or self.active[-1] == NMI):
            return self.lockup(f"{kind} fault at {self.img.where(pc)} inside {exc_name(self.active[-1])}")
        shcsr = ppb.regs.get(0xED24, 0)
        if shcsr & ena and self.group(self.priority(target)) < self.exec_priority():
            return self.enter_exception(target, pc)
        ppb.regs[ppb.HFSR] = ppb.regs.get(ppb.HFSR, 0) | HFSR_FORCED
        return self.enter_exception(HARDFAULT, pc)

    def lockup(self, why: str) -> bool:
        self.halted = "lockup"
        self.event("lockup", f"LOCKUP: {why}")
        self.exc_log.append({"t": self.now(), "what": "lockup", "why": why})
        return True

    # -- resets ------------------------------------------------------------------------------------------------
    def request_reset(self, cause: str, why: str):
        if self.reset_req is None:
            self.reset_req = (cause, why)
        self.req = "reset"
        self.uc.emu_stop()

    def do_reset(self, cause: str, why: str) -> bool:
        """A system reset: RAM kept, peripherals and core at reset values, RCC_CSR flags accumulated."""
        uc = self.uc
        old_csr = self.rcc.regs.get(Rcc.CSR, 0) & 0xFF00_0000
        self.event("reset", f"RESET ({cause}): {why}")
        self.boots[-1]["end"] = {"t": self.now(), "cause": cause, "why": why}
        self.tx_inflight = []
        self._map_peripherals()
        self.rcc.regs[Rcc.CSR] = (self.rcc.regs[Rcc.CSR] & 0x00FF_FFFF) | old_csr | RESET_FLAGS.get(cause, 0)
        self.t_base, self.insn_base, self.hz = self.now(), self.insns, float(boot.HSI_HZ)
        self.ppb.st_t0 = self.now()
        self.active, self.sys_pending = [], set()
        self.halted, self.fault, self.reset_req = None, None, None
        self.event_flag = False
        self.exc_depth = 0
        for r in ALL_GPR:
            uc.reg_write(r, 0)
        uc.reg_write(UC_ARM_REG_CONTROL, 0)
        uc.reg_write(UC_ARM_REG_PRIMASK, 0)
        uc.reg_write(UC_ARM_REG_BASEPRI, 0)
        uc.reg_write(UC_ARM_REG_FAULTMASK, 0)
        uc.reg_write(UC_ARM_REG_IPSR, 0)
        uc.reg_write(UC_ARM_REG_XPSR, 0x0100_0000)
        uc.reg_write(UC_ARM_REG_LR, 0xFFFF_FFFF)
        self.reidentify()
        vec = self._reset_vector()
        uc.reg_write(UC_ARM_REG_MSP, vec[0])
        uc.reg_write(UC_ARM_REG_SP, vec[0])
        self.pc_next = vec[1] & ~1
        self.boots.append({"t": self.now(), "cause": cause, "why": why, "insn": self.insns,
                           "csr_flags": RESET_FLAGS.get(cause, 0)})
        if len(self.boots) - 1 > self.max_resets:
            self.stop_kind, self.stop_msg = "reset-cap", f"more than {self.max_resets} resets"
            return False
        return True

    # -- events ------------------------------------------------------------------------------------------------
    def at(self, t: float, fn):
        """Schedule fn() at virtual time t."""
        self._seq += 1
        self.timed.append((t, self._seq, fn))
        self.timed.sort(key=lambda e: (e[0], e[1]))
        self.next_check = 0

    def timer_next(self, tim) -> float:
        """Virtual time of the next compare/overflow flag of a counting timer with an interrupt enabled."""
        dier = tim.regs.get(0x0C, 0) & 0x1F
        if not (tim.regs.get(tim.CR1, 0) & 1 and dier):
            return math.inf
        arr = tim.regs.get(tim.ARR, 0) or ((1 << tim.bits) - 1)
        rate = tim.clock() / (tim.regs.get(tim.PSC, 0) + 1)
        c = tim.count()
        best = math.inf
        if dier & 1:
            best = arr + 1 - c
        for ch in range(4):
            if not dier & (2 << ch):
                continue
            ccmr = tim.regs.get(0x18 + 4 * (ch >> 1), 0)
            if (ccmr >> (8 * (ch & 1))) & 3:
                continue
            ccr = tim.regs.get(0x34 + 4 * ch, 0)
            d = (ccr - c) % (arr + 1)
            best = min(best, d if d > 0 else arr + 1)
        return self.now() + best / rate if rate else math.inf

    def next_event(self) -> float:
        t = [self.block("IWDG").expiry()]
        if self.timed:
            t.append(self.timed[0][0])
        t.append(self.ppb.st_next_event())
        for _, done in [(x, x[4]) for x in self.tx_inflight]:
            t.append(done)
        for name in ("TIM2", "TIM3", "TIM4", "TIM5"):
            t.append(self.timer_next(self.block(name)))
        return min(t)

    def process_due(self) -> None:
        """Everything due by now: scheduled callbacks, DMA transmissions, the IWDG."""
        now = self.now()
        while self.timed and self.timed[0][0] <= now + 1e-12:
            _, _, fn = self.timed.pop(0)
            fn()
        if self.tx_inflight:
            keep = []
            for item in self.tx_inflight:
                dma, n, usart, data, t_done = item
                if t_done <= now + 1e-12:
                    dma.complete(n)
                    usart.tx_busy = False
                    self.tx_log.append({"usart": usart.name, "t_us": round(now * 1e6, 1), "bytes": data.hex()})
                    if usart.name == "USART2":
                        self.bus_tx += data
                        self.on_bus_frame(data)
                else:
                    keep.append(item)
            self.tx_inflight = keep
        if self.block("IWDG").expiry() <= now + 1e-12 and self.reset_req is None:
            self.request_reset("iwdg", f"IWDG expired at {now:.6f} s (counter reached 0)")

    def tx_start(self, dma, n, data, usart):
        super().tx_start(dma, n, data, usart)
        self.next_check = 0

    def tx_complete_all(self) -> bool:  # completions are timed events here
        return False

    # -- the run loop ------------------------------------------------------------------------------------------
    def _c_callback(self, addr, size, reason):
        """Called by the C block hook when a block needs Python (see fastblock)."""
        try:
            uc = self.uc
            if reason & 8:  # outside the instruction table (code in RAM, the boot alias)
                self._st.insns += self.img.insns_in(addr, size) - 1
            if reason & 2 and self._slice_over(addr, size):
                return
            if reason & 1:
                self._hot_block(uc, addr)
            if reason & 2 and self._st.insns >= self._st.next_check:
                self._async_check()
            if reason & 4:
                self._spin_window_end()
        except BaseException as e:  # noqa: BLE001
            if self.uc._hook_exception is None:
                self.uc._hook_exception = e
            self.uc.emu_stop()

    def _on_block(self, uc, addr, size, _):
        """Per-block hook in Python (when no C compiler: fastblock's fw_block does the same in C)."""
        if self._flash_fix is not None:
            self.flash_sync()
        st = self._st
        key = (addr << 12) | size
        n = self.ninsn.get(key)
        if n is None:
            n = self.ninsn[key] = self.img.insns_in(addr, size)
        st.insns += n
        st.last_addr, st.last_size = addr, size
        if st.insns >= st.next_check and self._slice_over(addr, size):
            return
        if addr in self.hot:
            self._hot_block(uc, addr)
        if st.insns >= st.next_check:
            self._async_check()
        if not st.win_over:
            if addr not in self._win_py:
                if len(self._win_py) < 8:
                    self._win_py.add(addr)
                else:
                    st.win_over = 1
        if st.insns - st.win_start >= st.spin_window:
            self._spin_window_end()

    _win_py = set()

    def _take_window(self):
        """The blocks of the window that ends (None if more than 8) and a fresh window."""
        st = self._st
        if self.c_hook:
            blocks = None if st.win_over else {st.win[i] for i in range(st.nwin)}
        else:
            blocks = None if st.win_over else set(self._win_py)
            self._win_py = set()
        st.nwin, st.win_over = 0, 0
        st.win_start = st.insns
        return blocks

    def _hot_block(self, uc, addr):
        if addr in self.trap_names:
            self.handler_hits[addr] += 1
            if self.handler_hits[addr] == 1 or self.args.verbose:
                self.event("handler", f"reached {self.trap_names[addr]}")
        if addr in self.special:
            self.special[addr](uc)
        if addr in self.img.task_polls:
            self.polled[addr] += 1

    # The host-time slices of a run: Python stops the emulation at a block's start once the slice is over, never
    # unicorn's emu_start timeout (only a backstop): that stops inside an instruction, which runs again on resume with
    # its MMIO or flash side effects repeated (a flash key written twice locks the flash interface until reset).
    SLICE_INSNS = 2_000_000  # Python looks at least this often (next_check)
    slice_end = math.inf

    def _slice_over(self, addr: int, size: int) -> bool:
        """The slice is over: stop before this block runs (its instructions, counted on entry, are taken back: they
        are counted when it runs on resume)."""
        if time.monotonic() < self.slice_end:
            return False
        self._st.insns -= self.img.insns_in(addr, size)
        self.req = "slice"
        self.uc.emu_stop()
        return True

    def _async_check(self):
        self.process_due()
        if self.req or self.halted:
            return
        best = self.best_pending()
        if best is not None:
            self.req = "preempt"
            self.uc.emu_stop()
            return
        if self._masked_pending:
            self.next_check = self.insns + 64  # masked (PRIMASK/BASEPRI): look again soon
            return
        gap = (self.next_event() - self.now()) * self.hz
        self.next_check = self.insns + max(1, int(min(gap, self.SLICE_INSNS)))

    def _spin_window_end(self):
        blocks, mmio = self._take_window(), self.mmio_count - self.win_mmio
        self.win_mmio = self.mmio_count
        if blocks is None or len(blocks) > 6 or mmio:
            return
        key = frozenset(blocks)
        known = any(key <= k for k in self.known_spins)
        if not known:
            self.spin_seen[key] += 1  # cumulative: interrupts in between do not reset it
            if self.spin_seen[key] < self.spin_windows:
                return
            self.known_spins.append(key)
            self.event("spin", f"spin loop at {self.img.where(min(blocks))} (context "
                               f"{exc_name(self.active[-1]) if self.active else 'thread'}): fast-forwarded to "
                               "each next event from now on")
        self.spins_skipped += 1
        self.req = "spin"
        self.uc.emu_stop()

    def _short_window_if_spin(self, pc):
        """Back into a known spin loop: look again after a short window, not a full one."""
        if any(pc in k for k in self.known_spins):
            self._take_window()
            self.win_mmio = self.mmio_count
            self.win_start = max(self.insns - self.spin_window + 2000, 0)

    def _emu(self, pc: int) -> str:
        """One stretch of execution from pc: returns what stopped it."""
        uc = self.uc
        self.req = None
        self.next_check = 0
        err = None
        remaining = self.deadline - time.monotonic()
        if remaining <= 0:
            self.stop_kind, self.stop_msg = "timeout", f"host-time budget exhausted ({self.timeout_s:g} s)"
            return "stop"
        self.slice_end = time.monotonic() + min(1.0, remaining)
        try:
            uc.emu_start(pc | 1, self.UNTIL, timeout=int((remaining + 5.0) * 1e6))  # a backstop only
        except UcError as e:
            err = e
        self.flash_sync()
        pc = uc.reg_read(UC_ARM_REG_PC)
        self.pc_next = pc
        if self.stop_kind:
            return "stop"
        if self.req == "reset" or self.reset_req:
            return "reset"
        if err is not None:
            img = self.img
            if err.errno == ucc.UC_ERR_INSN_INVALID and (pc in img.wfe or pc - 2 in img.wfe or pc in img.wfi
                                                          or pc - 2 in img.wfi):
                at = pc if (pc in img.wfe or pc in img.wfi) else pc - 2
                self.insns += 1
                self.pc_next = at + 2
                if at in img.wfe and self.event_flag:
                    self.event_flag = False
                    self.wfe_wakeups += 1
                    return "continue"
                self.idle_pc = at
                return "idle"
            if err.errno == ucc.UC_ERR_EXCEPTION and pc >= 0xFFFF_FFE0:
                self.exc_ret = pc | 1
                return "exc-return"
            if self.fault is not None:
                return "fault"
            if err.errno == ucc.UC_ERR_INSN_INVALID:
                self.fault = {"kind": "usage", "addr": None, "pc": pc, "access": "undefined instruction"}
                return "fault"
            self.fault = self.fault or {"kind": "bus", "addr": None, "pc": pc, "access": str(err)}
            return "fault"
        if self.req in ("preempt", "spin", "fault"):
            return self.req
        if pc == self.UNTIL:
            self.fault = {"kind": "bus", "addr": pc, "pc": pc, "access": "instruction fetch"}
            return "fault"
        return "continue"  # a host time slice ended

    def _fault_access(self, kind, addr, size, value=None):
        """An invalid access (unicorn hook): a precise BusFault at the faulting instruction."""
        if self.fault is None:
            self.fault = {"kind": "bus", "addr": addr, "pc": self.pc(), "access": kind}
        self.req = "fault"

    def _overflow(self, sp, addr, culprit_block):
        """SP left the stack region: on the chip nothing happens until an access faults (flip-link: below SRAM
        is unmapped). Recorded, not a stop."""
        if self.overflow is None:
            self.overflow = {"sp": sp, "pc": addr, "t": self.now(), "function": self.img.func_at(addr)[0]}
            self.event("sp_out", f"SP=0x{sp:08x} left the stack region at {self.img.where(addr)}")

    def run_until(self, t_end: float, timeout_s: float = 60.0, until=None) -> str:
        """Runs the chip until virtual time t_end (or `until()` is true at an idle/event point, or the run
        stops). Returns "time" | "until" | the stop kind."""
        self.deadline = time.monotonic() + timeout_s
        self.timeout_s = timeout_s
        self.idle = False
        while True:
            if self.stop_kind:
                return self.stop_kind
            if until is not None and until():
                return "until"
            if self.reset_req:
                cause, why = self.reset_req
                if not self.do_reset(cause, why):
                    return self.stop_kind
                continue
            if self.halted:
                # nothing executes: time runs to the next event that can end it (the IWDG; NMI for a clock halt)
                t = min(self.next_event(), t_end)
                if t == math.inf:
                    self.stop_kind, self.stop_msg = "halted", f"core halted ({self.halted}) with no watchdog"
                    return self.stop_kind
                self.skip_time(max(0.0, t - self.now()))
                self.process_due()
                if self.now() >= t_end and not self.reset_req:
                    return "time"
                continue
            if self.now() >= t_end:
                return "time"
            self.process_due()
            if self.reset_req:
                continue
            best = self.best_pending()
            if best is not None:
                if not self.enter_exception(best[1], self.pc_next):
                    return self.stop_kind or "stop"
                continue
            r = self._emu(self.pc_next)
            if r == "stop":
                return self.stop_kind
            if r == "reset":
                continue
            if r == "exc-return":
                self.exception_return(self.exc_ret)
                continue
            if r == "fault":
                f = self.fault
                self.fault = None
                pc = f.get("pc", self.pc_next)
                if f.get("access") == "instruction fetch" and self.active == [] and pc >= 0xF000_0000:
                    pass
                self.raise_fault(f["kind"], f.get("addr"), pc, f.get("access", ""))
                continue
            if r in ("idle", "spin"):
                if until is not None and until():
                    return "until"  # before time jumps to the next event
                self.process_due()
                if self.reset_req or self.best_pending() is not None:
                    continue  # something became pending in the last block: taken (WFE wakes up)
                t = min(self.next_event(), t_end)
                if t == math.inf:
                    self.stop_kind, self.stop_msg = "idle-forever", "idle with no event to come"
                    return self.stop_kind
                self.skip_time(max(0.0, t - self.now()))
                self.process_due()
                if r == "spin":
                    self._short_window_if_spin(self.pc_next)
                continue

    def _reset_vector(self):
        """SP and PC from the vector table at reset (boot.Machine.boot_vector), VTOR set for a direct boot."""
        sp, pc, vtor = self.boot_vector()
        if vtor:
            self.ppb.regs[Ppb.VTOR] = vtor
            if not any(e["kind"] == "direct_boot" for e in self.events):
                self.event("direct_boot", f"0x0800_0000 erased: started from the vector table at 0x{vtor:08x} "
                                          "(VTOR set there, as a bootloader would)")
        return sp, pc

    def power_on(self):
        vec = self._reset_vector()
        self.uc.reg_write(UC_ARM_REG_SP, vec[0])
        self.initial_sp, self.reset_pc = vec[0], vec[1]
        self.pc_next = vec[1] & ~1
        self._sources = self.irq_sources()
        self.insn_limit = 1 << 62

    pc_next = 0
    exc_ret = 0

    # -- stimuli -----------------------------------------------------------------------------------------------
    def feed_rx(self, usart_name: str, dma_name: str, stream: int, data: bytes, t0: float, baud: float,
                chunk: int = 0, idle: bool = True):
        """Bytes arriving on a USART from t0 at `baud` (10 bits per byte), in chunks (0: at once), the line idle
        after each chunk. Line errors in force (`line_errors`) flag the bytes."""
        usart, dma = self.block(usart_name), self.block(dma_name)
        chunk = chunk or len(data)
        for i in range(0, len(data), chunk):
            part = data[i:i + chunk]
            t = t0 + (i + len(part)) * 10 / baud

            def deliver(part=part, t=t, usart_name=usart_name, dma_name=dma_name):
                u, d = self.block(usart_name), self.block(dma_name)
                err = self.line_error_at(usart_name, t)
                u.bytes_in(d, stream, part, err)
                if idle:
                    u.idle = True
                self.poke()
            self.at(t, deliver)
        del usart, dma

    def line_errors(self, usart_name: str, t0: float, t1: float, flags: int = FE):
        self.usart_errors.append((usart_name, t0, t1, flags))

    def line_error_at(self, usart_name, t) -> int:
        f = 0
        for name, t0, t1, flags in self.usart_errors:
            if name == usart_name and t0 <= t < t1:
                f |= flags
        return f

    def fail_hse_at(self, t: float):
        def fail():
            self.hse_dead = True
            r = self.rcc.hse_failure()
            if r == "halt":
                self.halted = "clock"
        self.at(t, fail)


def sym_addr(img, name):
    a = img.addr_of.get(name)
    if a is None:
        for k, v in img.addr_of.items():
            if k.endswith("::" + name):
                return v
    return a
