#!/usr/bin/env python3
"""Boot test of the REAL flight ELF on an emulated Cortex-M4 (unicorn), up to the executor's first idle.

Usage:
    python3 tools/fw-check/boot.py target/thumbv7em-none-eabihf/fw/firmware \
        [--json out.json] [--max-stack-percent 80] [--require-iwdg-before-clock] [-v]
        [--frames FILE|synth[:N] [--fused N] [--frame-rate 604.8] [--max-frames 400]]
        [--flash-timing typ|max] [--flash-bsy-polls N]

Exit status 0 only if the boot reached idle and every assertion passed; 1 if an assertion failed or the boot
faulted/hung; 2 on a usage or tooling error (missing ELF, missing llvm-objdump, ...).

Why unicorn and not QEMU
------------------------
QEMU 7.2's `netduinoplus2` (an STM32F405) has no RCC, PWR, FLASH-interface or DMA model: unimplemented registers
read 0, so embassy-stm32's clock init spins on the first ready bit and never reaches `main`. We "rehost" instead:
unicorn (QEMU's CPU core without devices) executes the firmware's Thumb-2 code unchanged, and this script models the
chip around it: the memory map, and the peripherals as register files (a read returns what was last written, with
the reset values that matter) plus the status bits a real F405 sets on its own (oscillator/PLL ready, clock switch
status, USART TXE/TC, ADC STRT/EOC, timers counting, ...).

What is modelled
----------------
* Memory: flash 1 MiB at 0x0800_0000 (erased = 0xFF outside the image, aliased at 0x0000_0000: one buffer seen at
  both addresses; changed only by programming and erasing through the flash interface, see below), SRAM 128 KiB at 0x2000_0000, CCM 64 KiB at 0x1000_0000 (no execute), system memory 0x1FFF_0000..0x1FFF_7A2F
  (read only; unique ID, flash size and the factory calibration words VREFINT_CAL / TS_CAL1 / TS_CAL2 carry plausible
  values). Nothing else: 0x1FFF_7A30..0x1FFF_FFFF (just below SRAM, where a flip-link stack overflow goes) and
  0x2002_0000.. are unmapped, so an access there is a fault, as the BusFault it is on the chip. RAM that the reset
  handler does not initialise (stack, .uninit, CCM, the rest) holds deterministic pseudo-random "power-on garbage";
  the stack region is painted with a known pattern to measure its high-water mark.
* Peripherals 0x4000_0000..0x4007_FFFF and 0x5000_0000..0x5006_0FFF: register files, with behaviour for RCC (ready
  bits follow their enables, SWS follows SW when the source is ready, reset flags POR|PIN|BOR at power-on, RMVF),
  PWR (VOSRDY), FLASH interface (programs and erases the flash: "Flash programming and erase"), USART1/2 (TXE|TC, BRR, bytes written to DR are
  collected), DMA1/2 (register file; EN reads back; no data moves), general-purpose timers (CNT counts at
  f_timer/(PSC+1) of the modelled virtual time, see below), IWDG (key writes logged, PR/RLR locked unless 0x5555,
  SR = 0), ADC1 (SWSTART sets STRT|EOC, DR gives a plausible code for the temperature / VREFINT channels), GPIO (BSRR,
  IDR = ODR for outputs). Any other peripheral block is a plain register file and its first access is logged.
* PPB 0xE000_0000..0xE00F_FFFF: SCB (CPUID 0x410F_C241, VTOR (exceptions are vectored through it), AIRCR - a SYSRESETREQ ends the run as a failure -
  CCR, SHPR, CFSR, CPACR, ...), NVIC (ISER/ICER/ISPR/ICPR/IPR/STIR as bitmaps), SysTick, DWT (CYCCNT = modelled
  cycles when enabled), DCB DEMCR, FPU FPCCR, DBGMCU (0xE004_2000).
* Time: "virtual time" = instructions executed / HCLK of the moment (from the modelled RCC registers), i.e. one
  instruction per cycle. Timers and DWT.CYCCNT derive from it. This is an approximation (the real M4 with 5 flash
  wait states and the ART accelerator is close to, but not exactly, 1 IPC); it only has to make busy-waits terminate
  and time move forward monotonically.
* Idle: embassy's thread executor runs `loop { poll(); wfe }`. The event register is modelled: a `SEV` sets it; at
  `WFE`, if set, it is cleared and execution continues; if not set the real core would sleep until an interrupt,
  which we do not deliver: the executor is idle, the boot is over, and the assertions are checked.

Diagnostics (not assertions)
----------------------------
* The firmware's defmt log, decoded from the raw bytes handed to `_defmt_write` (format strings from the ELF's
  defmt symbols; a small decoder for the defmt 1.x wire format, hex where it cannot decode).
* A hang is reported as "STUCK": the same peripheral register read with the same value `--spin-limit` times in a row
  (a ready bit the model does not set, or hardware that never gets ready), or the host-time / instruction budget
  exhausted; with the hottest code blocks and the most-read registers of the last time slices.
* Events with instruction index and virtual time: PLLON, clock switches, flash latency, IWDG start, DMA stream
  enables, CPACR; first access to each peripheral (-v); writes the hardware would ignore (PLLCFGR while the PLL runs,
  IWDG PR/RLR while locked, SW selecting a clock that is not ready, ...).
* NVIC: enabled interrupts and their priorities, and those enabled with `DefaultHandler` as their vector.
* A static scan of the largest explicit frames (`sub sp, #N`), each marked reached or not in this boot.

Stretch mode: --frames FILE (or synth[:N])
------------------------------------------
After the boot checks, the FPGA byte stream is fed into USART1's RX DMA ring (DMA2 stream 2): one 240-byte chunk
per frame period of virtual time (`--frame-rate`, the core "sleeps" in between), written at the ring's write
position with NDTR counting down (HTIF/TCIF at the half and the end), then USART1's IDLE flag. Interrupts are
then delivered, level-triggered from the modelled peripheral state (USART IDLE/TC with IDLEIE/TCIE, DMA HT/TC with
HTIE/TCIE, timer compare/update flags with DIER, NVIC ISPR/STIR), only while the thread is idle at WFE, enabled
ones only, lowest IRQ number first: the context is saved, a 26-word frame is pushed on MSP, LR = EXC_RETURN, the
handler runs until it branches to EXC_RETURN, the context is restored and the event register set. A DMA
memory-to-USART transfer is captured when its stream is enabled and completes (NDTR 0, EN 0, TCIF, USART TC) at
the next idle after the line time at the configured baud rate. USART2's transfers are parsed as KISS + CSP v1 +
`[version] ++ postcard(Telemetry)`; the run stops at the `--fused N`-th `Fused` report (default 1). `synth[:N]`
generates N valid frames (mid-scale ADC codes, CRC-32C). Not modelled there: preemption of running code (interrupts
wait for idle), priorities, UART errors, the FPGA's answer to control messages.

Flash programming and erase (class FlashIf; RM0090 §3.5-3.9, DS8626)
---------------------------------------------------------------------
* Sectors: 0-3 16 KiB, 4 64 KiB, 5-11 128 KiB (RM0090 table 5, single bank). Erased = 0xFF.
* FLASH_KEYR: KEY1 0x4567_0123 then KEY2 0xCDEF_89AB clears CR.LOCK; any other value while locked (or the right
  ones in the wrong order) locks CR until the next reset and is a bus error (a fault here; a BusFault in emu.Sim).
  A key written while unlocked is reported and ignored.
* FLASH_CR: LOCK is write-1-only; while locked every write is ignored (and reported if it would change it). STRT
  starts a sector erase (SER, SNB 0..11) or a mass erase (MER); SNB > 11, or STRT with neither, is reported and
  refused (SNB > 11 sets WRPERR). PSIZE sets the parallelism: a program must be of that size (else PGPERR) and the
  erase time depends on it. EOPIE/ERRIE: EOP is set at the end of an operation only with EOPIE, OPERR only with
  ERRIE and a parallelism, alignment or write-protection error (RM0090 §3.9.5); the FLASH interrupt (IRQ 4) is a
  level source of EOP&EOPIE | OPERR&ERRIE.
* FLASH_SR: EOP, OPERR, WRPERR, PGAERR, PGPERR, PGSERR are write-1-to-clear. BSY: the CPU stalls for the whole
  operation (one bank: every instruction fetch from flash waits), so virtual time moves on by the operation's
  duration at once; BSY then reads as set for N reads of SR (--flash-bsy-polls; emu.Sim flash_bsy_polls; default 1) so that
  the driver's wait loop runs. A write of CR ends them (a CR write while BSY stalls the bus until the end).
* A store to flash memory (0x0800_0000.. or the alias 0..) is a program attempt: with PG set, unlocked, of PSIZE's
  size, inside one 128-bit row (else PGAERR) and not write-protected, the flash holds old AND value ("successive
  write operations are possible without the need of an erase operation when changing bits from 1 to 0", RM0090
  §3.6.2: no error flag on the F4); a program that leaves other bits than stored (over a non-erased location) is
  counted and reported. Without PG, or while CR is locked, the store does not program, PGSERR is set and the write
  is reported (RM0090 does not say what a store with PG set after LOCK does: refused here, conservatively).
* Durations (DS8626 table "Flash memory programming", VDD 2.7-3.6 V; --flash-timing max (default) or typ):
  sector erase 16 KiB x8/x16/x32 0.4/0.3/0.25 s typ, 0.8/0.6/0.5 s max; 64 KiB 1.2/0.7/0.55 s typ, 2.4/1.4/1.1 s
  max; 128 KiB 2/1.3/1 s typ, 4/2.6/2 s max; mass erase 16/11/8 s typ, 32/22/16 s max; word (any size) program
  t_prog 16 µs typ, 100 µs max. PSIZE x64 needs VPP (not on this board): timed as x32, with a warning. Timers,
  SysTick and the IWDG see the stall (they run on); in emu.Sim an IWDG expiry during an erase resets the chip at
  the expiry and leaves the sector pseudo-random (an interrupted erase's contents are undefined).
* Per run (`Machine.flash_summary()`): each erase (sectors, start, duration, PSIZE, cut short?), unlocks, programs,
  bytes, program time, over-programs and every violation (`flash_violation`: also a warning; boot.py's assertion
  "flash interface used as RM0090 says" fails on any).
* Implementation: both flash mappings are writable RAM to unicorn with a store hook that runs before the store and
  a fix-up afterwards when the flash must not hold the stored value (a refused or over-program); the fix-up is
  applied at the next block, flash-interface access or flash store, so a read of that location in the same
  translation block right after such a store would still see the stored value (never in a driver: it waits on SR
  in between). (unicorn 2.1.4's UC_HOOK_MEM_WRITE_PROT cannot be used: a "handled" write still stores, through a
  stale TLB entry, and crashed now and then.) emu.Sim does the common accesses in C (fastblock): ≈ 360 k word
  programs/s of embassy's unlock-program-wait-lock sequence on the build machine, ≈ 5.6 k/s in Python.
* Not modelled: the ART accelerator's caches (no stale line after a program or erase; DCRST/ICRST are accepted, and
  reported when written with the cache enabled, which RM0090 §3.9.1 forbids), option bytes (OPTCR reads its reset
  value 0x0FFF_AAED: no write protection, no readout protection; OPTKEYR/OPTCR writes are ignored with a warning),
  error flags blocking later operations, a program cut short by a reset, read-while-write timing of code running
  from RAM (stalled like code in flash), DWT.CYCCNT during the stall (it does not count it), the erase of the code
  being run (it is erased; execution then falls on 0xFFFF).

Several ELFs and images in one flash (class ImageSet)
-----------------------------------------------------
A run can load the bootloader ELF (at 0x0800_0000), the application ELF (at ACTIVE + 0x200) and raw images at given
addresses (a signed image in DFU, the boot state sector's words): `ImageSet(loaded, candidates, blobs)` (update.py
uses it). Execution starts from the vector table at 0 (the alias of 0x0800_0000). The ELFs whose flash contents are
all in place are identified at power-on, at every reset and at every VTOR write (the bootloader's jump); the
instruction table, symbols, traps, defmt decoders (each ELF its own), task polls and WFE/SEV/WFI follow (a
candidate ELF - the application in a DFU image - becomes active once the bootloader has copied it into place).
An application ELF alone whose vector table is not at 0x0800_0000 (linked behind a bootloader) starts from its own
vector table with VTOR set to it ("direct boot", an event), as if a bootloader had jumped to it.

What is NOT modelled
--------------------
* During the boot check no exception or interrupt is delivered (no SysTick, TIM5 alarms, DMA/USART interrupts,
  faults): a task that waits for one is simply left pending, which is what "idle" means here (--frames delivers
  peripheral interrupts afterwards, see above). A real fault shows up as the unicorn error
  at the faulting access (unmapped / protected memory, invalid instruction), reported with PC and function; reaching
  a fault handler, `DefaultHandler` or the panic path by a call is reported too.
* The FPU: unicorn executes VFP instructions whether or not CPACR enables CP10/CP11 (checked on unicorn 2.1.4), so
  a missing FPU enable would not fault here; the CPACR value written is checked as an assertion instead.
* DMA moves no data; UART receivers never receive; timers do not raise update/compare flags; the watchdog never
  bites (its configured timeout is reported); the clock tree is only as good as the rules above (no PLL lock time, no HSE failure: the
  crystal always starts, so the HSI fallback path of board.rs is not exercised).
* Instruction counts come from unicorn's translation blocks and llvm-objdump's instruction list: exact for what ran,
  but they are instructions, not M4 cycles.
* SP is checked at the start of the block after every block that may move it down, and at every faulting access;
  an SP excursion that starts and ends inside one block without touching memory out there goes unseen (harmless
  on the chip too: only accesses fault).

Scenario mode (emu.py, scenarios.py, faults.py)
----------------------------------------------
What this boot check leaves out is modelled there, on the same chip model: exceptions with priorities and
preemption of running code, SysTick, NMI, HardFault from faulting accesses (CFSR/HFSR/BFAR, stacking failure), the
IWDG counting on the LSI and resetting the core with RAM kept, SYSRESETREQ as a reset, a dead or failing crystal with
the clock security system, USART line errors, and the F4's DMA stream restart. `scenarios.py pil` is the
processor-in-the-loop differential test against `ground replay`; `scenarios.py faults` the fault-injection scenarios.

What the assertions prove (and do not)
-------------------------------------
* no fault / no stack overflow: this boot path (erased calibration slots, no bus traffic) runs from reset to the
  first idle without a fault, a panic, a reset request or the stack pointer leaving [_stack_end, _stack_start].
  Other paths (a stored calibration, traffic, interrupt handlers stacking on top of a task) are not exercised.
* stack high-water mark: max(deepest painted word overwritten, lowest SP seen) of this boot only; interrupt frames
  come on top on the real chip (8-26 words each, nested by priority).
* every task polled: each `TaskStorage<F>::poll` in the ELF (the main task and the spawned ones, counted from the
  ELF, named from DWARF) was entered at least once before idle.
* IWDG started, and when (instruction index and virtual time) relative to the first PLLON write (clock init);
  `--require-iwdg-before-clock` makes "before" mandatory.
* flash accelerator, clock tree, USART baud rates, RX DMA rings: the register values at idle, with the frequencies
  derived from them (8 MHz HSE), not compared as raw words only; flash wait states are also checked at every
  clock switch. The DMA ring buffers must be in SRAM (DMA cannot reach CCM) and outside the stack.
* `.ccmram` (NOLOAD) initialised: CCM starts with pseudo-random garbage here; every word of the section must have
  been written before idle (cortex-m-rt neither zeroes nor loads it).
* FPU enabled in CPACR.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import ctypes
import hashlib
import io
import json
import os
import random
import re
import shutil
import struct
import subprocess
import sys
import time

try:
    from elftools.elf.elffile import ELFFile
    from elftools.elf.sections import SymbolTableSection
except ImportError:  # pragma: no cover
    sys.exit("boot.py: needs pyelftools (pip install pyelftools)")
try:
    import unicorn
    from unicorn import (UC_ARCH_ARM, UC_HOOK_BLOCK, UC_HOOK_CODE, UC_HOOK_MEM_INVALID, UC_MODE_MCLASS,
                         UC_MODE_THUMB, UC_PROT_ALL, UC_PROT_EXEC, UC_PROT_READ, UC_PROT_WRITE, Uc, UcError)
    from unicorn.arm_const import (UC_ARM_REG_LR, UC_ARM_REG_PC, UC_ARM_REG_SP, UC_CPU_ARM_CORTEX_M4)
    import unicorn.unicorn_const as ucc
except ImportError:  # pragma: no cover
    sys.exit("boot.py: needs unicorn 2.1.x (pip install unicorn==2.1.4)")

class ToolError(Exception):
    """A usage or tooling problem (exit status 2), not a firmware failure."""


# ---------------------------------------------------------------------------------------------------------------
# The chip (STM32F405RG, RM0090 / DS8626)
# ---------------------------------------------------------------------------------------------------------------

FLASH_BASE, FLASH_SIZE = 0x0800_0000, 1 << 20
SRAM_BASE, SRAM_SIZE = 0x2000_0000, 128 << 10
CCM_BASE, CCM_SIZE = 0x1000_0000, 64 << 10
SYSMEM_BASE, SYSMEM_END = 0x1FFF_0000, 0x1FFF_7A30  # system memory, OTP, unique ID, flash size, calibration
UID_ADDR, FLASH_SIZE_ADDR = 0x1FFF_7A10, 0x1FFF_7A22
VREFINT_CAL_ADDR, TS_CAL1_ADDR, TS_CAL2_ADDR = 0x1FFF_7A2A, 0x1FFF_7A2C, 0x1FFF_7A2E
VREFINT_CAL, TS_CAL1, TS_CAL2 = 1500, 950, 1200  # plausible factory values (3.3 V, 30 C, 110 C)
PERIPH_WINDOWS = [(0x4000_0000, 0x8_0000), (0x5000_0000, 0x6_1000)]  # APB1, APB2, AHB1 | AHB2
PPB_BASE, PPB_SIZE = 0xE000_0000, 0x10_0000
HSE_HZ, HSI_HZ, LSI_HZ = 8_000_000, 16_000_000, 32_000

STACK_PAINT = 0xC5A5_5A5C  # a word the firmware is unlikely to write
ERASED = 0xFF

# Flash sectors of the 1 MiB single-bank F405 (RM0090 table 5): (start, size); index = SNB.
FLASH_SECTORS = [(FLASH_BASE + o, s) for o, s in
                 [(0x0000, 16 << 10), (0x4000, 16 << 10), (0x8000, 16 << 10), (0xC000, 16 << 10),
                  (0x1_0000, 64 << 10)] + [(0x2_0000 * i, 128 << 10) for i in range(1, 8)]]
# DS8626 table "Flash memory programming" (VDD 2.7-3.6 V): erase time (typ, max) in s by sector size and PSIZE
# (0 = x8, 1 = x16, 2 = x32; x64 needs VPP: modelled as x32), mass erase, and the word program time t_prog.
FLASH_ERASE_S = {16 << 10: [(0.4, 0.8), (0.3, 0.6), (0.25, 0.5)],
                 64 << 10: [(1.2, 2.4), (0.7, 1.4), (0.55, 1.1)],
                 128 << 10: [(2.0, 4.0), (1.3, 2.6), (1.0, 2.0)]}
FLASH_MASS_ERASE_S = [(16.0, 32.0), (11.0, 22.0), (8.0, 16.0)]
FLASH_PROGRAM_S = (16e-6, 100e-6)
FLASH_TIMING = {"typ": 0, "max": 1}


def flash_sector_of(addr: int):
    """(SNB, start, size) of the sector holding a flash address (0x0800_0000-based), or None."""
    for n, (start, size) in enumerate(FLASH_SECTORS):
        if start <= addr < start + size:
            return n, start, size
    return None

# RM0090 table 1 (F405/F407), 1 KiB blocks; name -> base
PERIPHERALS = {
    "TIM2": 0x4000_0000, "TIM3": 0x4000_0400, "TIM4": 0x4000_0800, "TIM5": 0x4000_0C00, "TIM6": 0x4000_1000,
    "TIM7": 0x4000_1400, "TIM12": 0x4000_1800, "TIM13": 0x4000_1C00, "TIM14": 0x4000_2000, "RTC/BKP": 0x4000_2800,
    "WWDG": 0x4000_2C00, "IWDG": 0x4000_3000, "I2S2ext": 0x4000_3400, "SPI2": 0x4000_3800, "SPI3": 0x4000_3C00,
    "I2S3ext": 0x4000_4000, "USART2": 0x4000_4400, "USART3": 0x4000_4800, "UART4": 0x4000_4C00,
    "UART5": 0x4000_5000, "I2C1": 0x4000_5400, "I2C2": 0x4000_5800, "I2C3": 0x4000_5C00, "CAN1": 0x4000_6400,
    "CAN2": 0x4000_6800, "PWR": 0x4000_7000, "DAC": 0x4000_7400,
    "TIM1": 0x4001_0000, "TIM8": 0x4001_0400, "USART1": 0x4001_1000, "USART6": 0x4001_1400, "ADC": 0x4001_2000,
    "SDIO": 0x4001_2C00, "SPI1": 0x4001_3000, "SYSCFG": 0x4001_3800, "EXTI": 0x4001_3C00, "TIM9": 0x4001_4000,
    "TIM10": 0x4001_4400, "TIM11": 0x4001_4800,
    **{f"GPIO{c}": 0x4002_0000 + 0x400 * i for i, c in enumerate("ABCDEFGHI")},
    "CRC": 0x4002_3000, "RCC": 0x4002_3800, "FLASH": 0x4002_3C00, "BKPSRAM": 0x4002_4000, "DMA1": 0x4002_6000,
    "DMA2": 0x4002_6400, "ETH": 0x4002_8000, "OTG_HS": 0x4004_0000, "OTG_FS": 0x5000_0000, "DCMI": 0x5005_0000,
    "RNG": 0x5006_0800,
}
BLOCK_SIZE = {"BKPSRAM": 0x1000, "ETH": 0x1400, "OTG_HS": 0x4_0000, "OTG_FS": 0x4_0000}
TIMERS_APB1 = {"TIM2", "TIM3", "TIM4", "TIM5", "TIM6", "TIM7", "TIM12", "TIM13", "TIM14"}
TIMERS_APB2 = {"TIM1", "TIM8", "TIM9", "TIM10", "TIM11"}
TIMERS_32BIT = {"TIM2", "TIM5"}

# F405/F407 interrupt numbers (RM0090 table 61), for readable reports.
IRQ_NAMES = dict(enumerate((
    "WWDG PVD TAMP_STAMP RTC_WKUP FLASH RCC EXTI0 EXTI1 EXTI2 EXTI3 EXTI4 DMA1_STREAM0 DMA1_STREAM1 DMA1_STREAM2 "
    "DMA1_STREAM3 DMA1_STREAM4 DMA1_STREAM5 DMA1_STREAM6 ADC CAN1_TX CAN1_RX0 CAN1_RX1 CAN1_SCE EXTI9_5 TIM1_BRK_TIM9 "
    "TIM1_UP_TIM10 TIM1_TRG_COM_TIM11 TIM1_CC TIM2 TIM3 TIM4 I2C1_EV I2C1_ER I2C2_EV I2C2_ER SPI1 SPI2 USART1 USART2 "
    "USART3 EXTI15_10 RTC_ALARM OTG_FS_WKUP TIM8_BRK_TIM12 TIM8_UP_TIM13 TIM8_TRG_COM_TIM14 TIM8_CC DMA1_STREAM7 FSMC "
    "SDIO TIM5 SPI3 UART4 UART5 TIM6_DAC TIM7 DMA2_STREAM0 DMA2_STREAM1 DMA2_STREAM2 DMA2_STREAM3 DMA2_STREAM4 ETH "
    "ETH_WKUP CAN2_TX CAN2_RX0 CAN2_RX1 CAN2_SCE OTG_FS DMA2_STREAM5 DMA2_STREAM6 DMA2_STREAM7 USART6 I2C3_EV I2C3_ER "
    "OTG_HS_EP1_OUT OTG_HS_EP1_IN OTG_HS_WKUP OTG_HS DCMI CRYP HASH_RNG FPU").split()))

# What the board is supposed to configure (firmware/src/board.rs).
EXPECT = {
    "sysclk": 168_000_000, "hclk": 168_000_000, "pclk1": 42_000_000, "pclk2": 84_000_000, "pll48": 48_000_000,
    "pllm": 4, "plln": 168, "pllp": 2, "pllq": 7, "latency": 5,
    "usart1_baud": 2_000_000, "usart2_baud": 115_200,
    # (controller, stream, channel, peripheral) of the RX rings
    "rx_dma": [("DMA2", 2, 4, "USART1"), ("DMA1", 5, 4, "USART2")],
}

HPRE_DIV = {0b1000: 2, 0b1001: 4, 0b1010: 8, 0b1011: 16, 0b1100: 64, 0b1101: 128, 0b1110: 256, 0b1111: 512}
PPRE_DIV = {0b100: 2, 0b101: 4, 0b110: 8, 0b111: 16}


def hpre_div(cfgr: int) -> int:
    return HPRE_DIV.get((cfgr >> 4) & 0xF, 1)


def ppre_div(cfgr: int, apb: int) -> int:
    return PPRE_DIV.get((cfgr >> (10 if apb == 1 else 13)) & 0x7, 1)


def pll_fields(pllcfgr: int) -> dict:
    return {"src": "HSE" if pllcfgr & (1 << 22) else "HSI", "m": pllcfgr & 0x3F, "n": (pllcfgr >> 6) & 0x1FF,
            "p": ((pllcfgr >> 16) & 3) * 2 + 2, "q": (pllcfgr >> 24) & 0xF}


def clock_tree(cr: int, pllcfgr: int, cfgr: int) -> dict:
    """Frequencies (Hz) from RCC_CR/PLLCFGR/CFGR as the hardware would produce them (SWS selects SYSCLK)."""
    f = pll_fields(pllcfgr)
    src_hz = HSE_HZ if f["src"] == "HSE" else HSI_HZ
    vco_in = src_hz / f["m"] if f["m"] >= 2 else 0.0
    vco = vco_in * f["n"]
    pll_p = vco / f["p"]
    pll_q = vco / f["q"] if f["q"] >= 2 else 0.0
    sws = (cfgr >> 2) & 3
    sysclk = {0: HSI_HZ, 1: HSE_HZ, 2: pll_p}.get(sws, 0.0)
    hclk = sysclk / hpre_div(cfgr)
    d1, d2 = ppre_div(cfgr, 1), ppre_div(cfgr, 2)
    pclk1, pclk2 = hclk / d1, hclk / d2
    return {"sysclk_source": {0: "HSI", 1: "HSE", 2: "PLL"}.get(sws, "?"), "pll_source": f["src"],
            "pll_vco_in": vco_in, "pll_vco": vco, "pll_p": pll_p, "pll48": pll_q, "sysclk": sysclk, "hclk": hclk,
            "pclk1": pclk1, "pclk2": pclk2, "tim_apb1": pclk1 * (1 if d1 == 1 else 2),
            "tim_apb2": pclk2 * (1 if d2 == 1 else 2), "ahb_div": hpre_div(cfgr), "apb1_div": d1, "apb2_div": d2}


def usart_baud(pclk: float, brr: int, cr1: int) -> float:
    """RM0090 §30.3.4: baud = f_ck / (8 × (2 − OVER8) × USARTDIV)."""
    if cr1 & (1 << 15):  # OVER8: BRR[2:0] is the fraction in 1/8, BRR[3] must be 0
        div8 = (brr >> 4) * 8 + (brr & 7)
        return pclk / div8 if div8 else 0.0
    return pclk / brr if brr else 0.0


def mhz(hz: float) -> str:
    return f"{hz / 1e6:g} MHz"


# ---------------------------------------------------------------------------------------------------------------
# The image: segments, symbols, disassembly
# ---------------------------------------------------------------------------------------------------------------

RUST_ESCAPES = [("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$C$", ","), ("$RF$", "&"), ("$BP$", "*"),
                ("$u7b$", "{"), ("$u7d$", "}"), ("$u27$", "'"), ("$LP$", "("), ("$RP$", ")"), ("$SP$", "@"),
                ("$u5b$", "["), ("$u5d$", "]"), ("$u3b$", ";"), ("$u21$", "!"), ("$u2b$", "+"), ("..", "::")]


def tidy_rust_name(name: str) -> str:
    """llvm-cxxfilt leaves the legacy-mangling escapes ($LT$ ...) and the hash: make names readable."""
    for a, b in RUST_ESCAPES:
        name = name.replace(a, b)
    return re.sub(r"::h[0-9a-f]{16}$", "", name)


def demangle_legacy(sym: str) -> str:
    """Fallback when llvm-cxxfilt is missing: legacy Rust symbols (_ZN <len><ident>... E)."""
    m = re.match(r"_ZN((?:\d+.+?)+)E$", sym)
    if not m:
        return sym
    body, parts, i = m.group(1), [], 0
    while i < len(body) and body[i].isdigit():
        j = i
        while body[j].isdigit():
            j += 1
        n = int(body[i:j])
        parts.append(body[j:j + n])
        i = j + n
    return "::".join(p[1:] if p.startswith("_$") else p for p in parts)


class Image:
    def __init__(self, path: str, verbose: bool = False, need_stack: bool = True):
        self.path = path
        with open(path, "rb") as f:
            raw = f.read()
        self.sha256 = hashlib.sha256(raw).hexdigest()
        self.mtime = os.path.getmtime(path)
        try:
            elf = ELFFile(io.BytesIO(raw))
        except Exception as e:  # elftools.common.exceptions.ELFError and friends
            raise ToolError(f"boot.py: {path} is not an ELF file ({e})")
        if elf["e_machine"] != "EM_ARM":
            raise ToolError(f"boot.py: {path} is not an ARM ELF")
        self.segments = []  # (paddr, vaddr, data, memsz)
        # PT_LOAD segments that hold sections (a linker may also load the ELF and program headers, in front of
        # the first section: not part of the image)
        alloc = [(s["sh_addr"], s["sh_size"]) for s in elf.iter_sections() if s["sh_flags"] & 2 and s["sh_size"]]
        for seg in elf.iter_segments():
            if seg["p_type"] == "PT_LOAD" and seg["p_memsz"]:
                lo, hi = seg["p_vaddr"], seg["p_vaddr"] + seg["p_memsz"]
                if any(lo <= a < hi for a, _ in alloc):
                    self.segments.append((seg["p_paddr"], seg["p_vaddr"], seg.data(), seg["p_memsz"]))
        self.sections = {s.name: (s["sh_addr"], s["sh_size"]) for s in elf.iter_sections() if s["sh_addr"]}
        # symbols
        raw_syms, raw_objs = [], []
        self.addr_of = {}
        symtab = elf.get_section_by_name(".symtab")
        if not isinstance(symtab, SymbolTableSection):
            raise ToolError("boot.py: the ELF has no symbol table (build with symbols: the fw profile keeps them)")
        for s in symtab.iter_symbols():
            if not s.name:
                continue
            self.addr_of.setdefault(s.name, s["st_value"])
            if s["st_info"]["type"] == "STT_FUNC" and s["st_value"]:
                raw_syms.append((s["st_value"] & ~1, s["st_size"], s.name))
            elif s["st_info"]["type"] == "STT_OBJECT" and s["st_size"]:
                raw_objs.append((s.name, s["st_value"], s["st_size"]))
        names = self._demangle([n for _, _, n in raw_syms])
        funcs = {}
        preferred = ("DefaultHandler", "HardFault", "Reset")
        for (a, size, mangled), dem in zip(raw_syms, names):
            dem = tidy_rust_name(dem)
            if a in funcs:  # aliases: DefaultHandler for every unbound vector, HardFault/_HardFault, ...
                cur = funcs[a][1]
                if cur in preferred or (dem not in preferred and (cur[:1] != "_") <= (dem[:1] != "_")
                                        and len(cur) <= len(dem)):
                    continue
            funcs[a] = (size, dem, mangled)
        self.funcs = sorted((a, s, n, m) for a, (s, n, m) in funcs.items())
        self.func_addrs = [f[0] for f in self.funcs]
        self.demangled_by_mangled = {m: n for _, _, n, m in self.funcs}
        for mangled, dem in zip([n for _, _, n in raw_syms], names):
            self.addr_of.setdefault(tidy_rust_name(dem), self.addr_of.get(mangled))
        objnames = self._demangle([n for n, _, _ in raw_objs])
        self.objects = {tidy_rust_name(d): (v, sz) for (n, v, sz), d in zip(raw_objs, objnames)}
        self.stack_start = self.addr_of.get("_stack_start")
        self.stack_end = self.addr_of.get("_stack_end")
        if self.stack_start is None or self.stack_end is None:
            if need_stack:
                raise ToolError("boot.py: _stack_start/_stack_end not in the symbol table")
            # a bootloader without flip-link's _stack_end: the stack region is what SRAM leaves below its top
            self.stack_start = self.stack_start or SRAM_BASE + SRAM_SIZE
            self.stack_end = self.stack_end or SRAM_BASE
        in_flash = sorted(p for p, _, d, _ in self.segments if FLASH_BASE <= p < FLASH_BASE + FLASH_SIZE and d)
        # cortex-m-rt's vector table: where the reset vector is read from (0x0800_0000, or ACTIVE + 0x200 for an
        # application started by the bootloader)
        self.vector_table = self.sections.get(".vector_table", (in_flash[0] if in_flash else FLASH_BASE, 0))[0]
        # disassembly (instruction addresses, WFE/SEV/WFI, stack adjustments)
        self.insn_text = {}
        self._disassemble()
        self.insn_sorted = sorted(self.insn_text)
        self.task_labels = self._task_labels()
        self.task_polls = {a: self.task_labels.get(m, n) for a, _, n, m in self.funcs
                           if "TaskStorage<" in n and n.endswith("::poll")}

    # -- helpers ---------------------------------------------------------------------------------------------
    def flash_segments(self):
        """(address, bytes) of what the ELF puts into flash."""
        return [(p, d) for p, _, d, _ in self.segments if FLASH_BASE <= p < FLASH_BASE + FLASH_SIZE and d]

    def matches(self, flash) -> bool:
        """Whether the flash contents (a bytes-like of FLASH_SIZE from 0x0800_0000) hold this ELF's image."""
        segs = self.flash_segments()
        return bool(segs) and all(flash[p - FLASH_BASE:p - FLASH_BASE + len(d)] == d for p, d in segs)

    def label(self) -> str:
        return f"{os.path.basename(self.path)} (0x{self.vector_table:08x}, sha256 {self.sha256[:12]})"

    @staticmethod
    def _demangle(names):
        tool = shutil.which("llvm-cxxfilt") or shutil.which("rustfilt") or shutil.which("c++filt")
        if tool:
            try:
                out = subprocess.run([tool], input="\n".join(names), capture_output=True, text=True,
                                     check=True).stdout.split("\n")
                if len(out) >= len(names):
                    return out[:len(names)]
            except (OSError, subprocess.CalledProcessError):
                pass
        return [demangle_legacy(n) for n in names]

    def _disassemble(self):
        tool = shutil.which("llvm-objdump")
        if not tool:
            raise ToolError("boot.py: needs llvm-objdump (Debian package llvm) for the instruction list")
        out = subprocess.run([tool, "-d", "--no-show-raw-insn", "--triple=thumbv7em-none-eabihf", self.path],
                             capture_output=True, text=True)
        line_re = re.compile(r"^\s*([0-9a-f]+):\s+(\S.*)$")
        for line in out.stdout.splitlines():
            m = line_re.match(line)
            if not m:
                continue
            text = m.group(2).split("@")[0].strip()
            if not text or text.startswith(".") or re.match(r"^([0-9a-f]{2}\s)+", text):
                continue  # data ($d): .word/.short or raw bytes
            self.insn_text[int(m.group(1), 16)] = re.sub(r"\s+", " ", text)
        if not self.insn_text:
            raise ToolError("boot.py: llvm-objdump produced no instructions")
        self.wfe = {a for a, t in self.insn_text.items() if t.split()[0] in ("wfe", "wfe.w")}
        self.wfi = {a for a, t in self.insn_text.items() if t.split()[0] in ("wfi", "wfi.w")}
        self.sev = {a for a, t in self.insn_text.items() if t.split()[0] in ("sev", "sev.w")}

    def _task_labels(self) -> dict:
        """mangled TaskStorage::poll symbol -> task name, from the DWARF names ("poll<firmware::__pps_task::...>")."""
        tool = shutil.which("llvm-dwarfdump")
        labels = {}
        if not tool:
            return labels
        out = subprocess.run([tool, "--name=^poll<", "--regex", self.path], capture_output=True, text=True).stdout
        for die in out.split("\n\n"):
            lm = re.search(r'DW_AT_linkage_name\s+\("([^"]+)"\)', die)
            nm = re.search(r'DW_AT_name\s+\("([^"]+)"\)', die)
            if not (lm and nm and "TaskStorage" in lm.group(1)):
                continue
            t = re.search(r"::(_*)(\w+?)_task::", nm.group(1))
            label = (t.group(2) if t else nm.group(1)).lstrip("_")
            if label == "embassy_main":
                label = "main"
            labels[lm.group(1)] = label
        return labels

    def func_at(self, addr: int):
        """(name, start) of the function containing addr, or (None, None)."""
        addr &= ~1
        i = bisect.bisect_right(self.func_addrs, addr) - 1
        if i >= 0:
            a, size, name, mangled = self.funcs[i]
            if addr < a + max(size, 2):
                if a in self.task_polls:
                    name = f"{name} [task {self.task_polls[a]}]"
                return name, a
        return None, None

    def data_symbol(self, addr: int) -> str:
        """The object (static) containing addr, for RAM addresses."""
        if not hasattr(self, "_objs"):
            self._objs = sorted((v, sz, n) for n, (v, sz) in self.objects.items())
            self._obj_addrs = [o[0] for o in self._objs]
        i = bisect.bisect_right(self._obj_addrs, addr) - 1
        if i >= 0 and addr < self._objs[i][0] + max(self._objs[i][1], 1):
            return f"{self._objs[i][2]}+0x{addr - self._objs[i][0]:x}"
        return f"0x{addr:08x}"

    def where(self, addr: int) -> str:
        name, start = self.func_at(addr)
        return f"0x{addr:08x} in {name}+0x{addr - start:x}" if name else f"0x{addr:08x} (no symbol)"

    def insns_in(self, addr: int, size: int) -> int:
        lo = bisect.bisect_left(self.insn_sorted, addr)
        hi = bisect.bisect_left(self.insn_sorted, addr + size)
        return max(hi - lo, 1)

    def sp_writers(self, addr: int, size: int):
        """Instructions in [addr, addr+size) that move SP down (the culprit of an overflow)."""
        lo = bisect.bisect_left(self.insn_sorted, addr)
        hi = bisect.bisect_left(self.insn_sorted, addr + size)
        found = []
        for a in self.insn_sorted[lo:hi]:
            t = self.insn_text[a]
            if self.moves_sp(t):
                found.append((a, t))
        return found

    SP_DOWN = re.compile(r"^(v?push|stmdb(\.w)? sp!|vstmdb sp!|msr (msp|psp)|\S+ .*\[sp, #-\d+\]!)")
    SP_DEST = re.compile(r"^(\S+) sp[,!]")

    def moves_sp(self, t: str) -> bool:
        """Whether an instruction can move SP down (or set it outright): everything that writes SP except
        `add sp, #imm`, `pop` and the loads/compares that only read it."""
        if self.SP_DOWN.match(t):
            return True
        m = self.SP_DEST.match(t)
        return bool(m) and not re.match(r"^(add|pop|cmp|cmn|tst|teq|ldr|ldm|str|stm)", m.group(1)) or (
            bool(m) and m.group(1).startswith(("ldr", "ldm")))

    def block_info(self, addr: int, size: int):
        """(instructions in the block, whether it may move SP down)."""
        lo = bisect.bisect_left(self.insn_sorted, addr)
        hi = bisect.bisect_left(self.insn_sorted, addr + size)
        moves = any(self.moves_sp(self.insn_text[a]) for a in self.insn_sorted[lo:hi])
        return max(hi - lo, 1), moves or hi == lo

    def static_frames(self, top: int = 8):
        """Largest `sub sp, #N` of each function (an explicit frame; pushes come on top)."""
        frames = {}
        for a, t in self.insn_text.items():
            m = re.match(r"^sub(?:\.w|w)?s? sp, (?:sp, )?#(\d+)$", t)
            if m:
                _, start = self.func_at(a)
                if start is not None:
                    frames[start] = max(frames.get(start, 0), int(m.group(1)))
        ranked = sorted(frames.items(), key=lambda kv: -kv[1])[:top]
        return [(start, self.func_at(start)[0], n) for start, n in ranked]


class ImageSet(Image):
    """Several ELFs and raw binary images in one flash, presented as one Image (the update's bootloader at
    0x0800_0000, an application at ACTIVE + 0x200, a signed image in DFU, the boot state sector).

    `loaded`: ELFs whose flash contents are loaded at their addresses; `candidates`: ELFs that may come to be in
    flash during the run (the application in the DFU image, which the bootloader's swap copies to ACTIVE); `blobs`:
    (address, bytes, name) raw images written into flash after the ELFs (a later one wins where they overlap).
    The code in flash is identified at power-on and every reset and VTOR write (`identify`): every known ELF whose
    flash contents are all in place is *active*; the instruction table, symbols, task polls, WFE/SEV/WFI, traps and
    defmt decoders are the union of the active ELFs'. Stack bounds, sections, RAM objects and the reported path are
    the *primary* ELF's: the active one linked highest (the application, not the bootloader)."""

    def __init__(self, loaded, candidates=(), blobs=()):
        seen, self.known = set(), []
        for im in list(loaded) + list(candidates):
            if im.sha256 not in seen:
                seen.add(im.sha256)
                self.known.append(im)
        self.loaded = list(loaded)
        self.blobs = [(a, bytes(d), n) for a, d, n in blobs]
        for a, d, n in self.blobs:
            if not (FLASH_BASE <= a and a + len(d) <= FLASH_BASE + FLASH_SIZE):
                raise ToolError(f"boot.py: image {n} at 0x{a:08x} (+{len(d)} B) is not inside flash")
        self.segments = [s for im in self.loaded for s in im.segments] + [(a, a, d, len(d)) for a, d, _ in self.blobs]
        self.set_active(self.loaded or self.known[:1])

    def set_active(self, active):
        self.active = list(active)
        parts = self.active or self.known[-1:]
        p = self.primary = max(parts, key=lambda im: im.vector_table)
        order = [p] + [im for im in parts if im is not p]
        self.path, self.sha256, self.mtime = p.path, p.sha256, p.mtime
        self.sections, self.objects = p.sections, p.objects
        self.stack_start, self.stack_end, self.vector_table = p.stack_start, p.stack_end, p.vector_table
        self.insn_text = {}
        for im in reversed(order):
            self.insn_text.update(im.insn_text)
        self.insn_sorted = sorted(self.insn_text)
        self.wfe = set().union(*(im.wfe for im in parts))
        self.wfi = set().union(*(im.wfi for im in parts))
        self.sev = set().union(*(im.sev for im in parts))
        funcs = {}
        for im in reversed(order):
            funcs.update({f[0]: f for f in im.funcs})
        self.funcs = sorted(funcs.values())
        self.func_addrs = [f[0] for f in self.funcs]
        self.task_polls, self.task_labels, self.addr_of, self.demangled_by_mangled = {}, {}, {}, {}
        for im in order:
            self.task_polls.update(im.task_polls)
            self.task_labels.update(im.task_labels)
            for k, v in im.addr_of.items():
                self.addr_of.setdefault(k, v)
            for k, v in im.demangled_by_mangled.items():
                self.demangled_by_mangled.setdefault(k, v)
        self.__dict__.pop("_objs", None)

    def identify(self, flash) -> bool:
        """Which known ELFs are in flash now; True if that changed."""
        active = [im for im in self.known if im.matches(flash)]
        if [im.sha256 for im in active] == [im.sha256 for im in self.active]:
            return False
        self.set_active(active)
        return True

    def part_at(self, addr: int):
        """The active ELF whose code holds addr, or None."""
        for im in self.active:
            name, _ = im.func_at(addr)
            if name is not None:
                return im
        return None


# ---------------------------------------------------------------------------------------------------------------
# defmt: the firmware's log, decoded from the bytes it hands to `_defmt_write` (before defmt-rtt's rzCOBS)
# ---------------------------------------------------------------------------------------------------------------

class DefmtError(Exception):
    pass


class Defmt:
    """A small defmt 1.x wire-format decoder: frame = istr(u16 index) + timestamp + arguments (defmt/src/export).

    Enough for the firmware's own log lines and embassy's panics; anything it cannot parse is shown as hex."""

    INTS = {"u8": 1, "u16": 2, "u32": 4, "u64": 8, "u128": 16, "i8": 1, "i16": 2, "i32": 4, "i64": 8, "i128": 16,
            "usize": 4, "isize": 4}

    def __init__(self, img: Image):
        self.strings = {}
        self.timestamp = None
        for name, value in img.addr_of.items():
            if name.startswith('{"package"'):
                try:
                    d = json.loads(name)
                except ValueError:
                    continue
                self.strings[value] = (d.get("tag", ""), d.get("data", ""))
                if d.get("tag") == "defmt_timestamp":
                    self.timestamp = d.get("data")

    @staticmethod
    def _params(fmt: str):
        """Split a format string into literal text and parameters ({{ and }} are escapes)."""
        out, i, lit = [], 0, ""
        while i < len(fmt):
            c = fmt[i]
            if c == "{" and fmt.startswith("{{", i):
                lit += "{"
                i += 2
            elif c == "}" and fmt.startswith("}}", i):
                lit += "}"
                i += 2
            elif c == "{":
                j = fmt.index("}", i)
                out.append((lit, fmt[i + 1:j]))
                lit, i = "", j + 1
            else:
                lit += c
                i += 1
        out.append((lit, None))
        return out

    @staticmethod
    def _split_variants(fmt: str):
        parts, depth, cur = [], 0, ""
        for c in fmt:
            if c == "{":
                depth += 1
            elif c == "}":
                depth -= 1
            if c == "|" and depth == 0:
                parts.append(cur)
                cur = ""
            else:
                cur += c
        return parts + [cur]

    def _take(self, buf, n):
        if buf[1] + n > len(buf[0]):
            raise DefmtError("short frame")
        v = buf[0][buf[1]:buf[1] + n]
        buf[1] += n
        return v

    def _uint(self, buf, n):
        return int.from_bytes(self._take(buf, n), "little")

    def _value(self, typ: str, hint: str, buf) -> str:
        if typ in self.INTS:
            n = self.INTS[typ]
            v = self._uint(buf, n)
            if typ[0] == "i" and v >= 1 << (8 * n - 1):
                v -= 1 << (8 * n)
            if "x" in hint.lower():
                return ("0x" if "#" in hint else "") + format(v, "x")
            if "b" in hint and "us" not in hint:
                return ("0b" if "#" in hint else "") + format(v, "b")
            if hint == "us":
                return f"{v / 1e6:.6f}"
            if hint == "ms":
                return f"{v / 1e3:.3f}"
            return str(v)
        if typ == "bool":
            return str(bool(self._uint(buf, 1))).lower()
        if typ == "f32":
            return f"{struct.unpack('<f', self._take(buf, 4))[0]:g}"
        if typ == "f64":
            return f"{struct.unpack('<d', self._take(buf, 8))[0]:g}"
        if typ == "char":
            return chr(self._uint(buf, 4))
        if typ == "str":
            return self._take(buf, self._uint(buf, 4)).decode("utf-8", "replace")
        if typ == "istr":
            return self.strings.get(self._uint(buf, 2), ("", "?"))[1]
        if typ == "[u8]":
            return "[" + ", ".join(str(b) for b in self._take(buf, self._uint(buf, 4))) + "]"
        m = re.fullmatch(r"\[u8; *(\d+)\]", typ)
        if m:
            return "[" + ", ".join(str(b) for b in self._take(buf, int(m.group(1)))) + "]"
        if typ in ("__internal_Debug", "__internal_Display"):
            end = buf[0].find(b"\xff", buf[1])
            if end < 0:
                raise DefmtError("unterminated Display/Debug")
            text = buf[0][buf[1]:end].decode("utf-8", "replace")
            buf[1] = end + 1
            return text
        if typ == "?":
            return self._format(self._uint(buf, 2), buf)
        m = re.fullmatch(r"\[\?\]", typ)
        if m:
            n, tag = self._uint(buf, 4), self._uint(buf, 2)
            return "[" + ", ".join(self._format(tag, buf) for _ in range(n)) + "]"
        m = re.fullmatch(r"\[\?; *(\d+)\]", typ)
        if m:
            tag = self._uint(buf, 2)
            return "[" + ", ".join(self._format(tag, buf) for _ in range(int(m.group(1)))) + "]"
        m = re.fullmatch(r"(\d+)\.\.(\d+)", typ)
        if m:  # bitfield: the smallest uint holding the highest bit
            hi = int(m.group(2))
            n = 1 if hi <= 8 else 2 if hi <= 16 else 4 if hi <= 32 else 8
            v = self._uint(buf, n)
            return str((v >> int(m.group(1))) & ((1 << (hi - int(m.group(1)))) - 1))
        raise DefmtError(f"type {typ!r}")

    def _format(self, index: int, buf) -> str:
        tag, fmt = self.strings.get(index, (None, None))
        if fmt is None:
            raise DefmtError(f"unknown string index {index}")
        if tag in ("defmt_derived", "defmt_prim", "defmt_bitflags") and "|" in fmt:
            variants = self._split_variants(fmt)
            disc = self._uint(buf, 1 if len(variants) <= 256 else 2)
            if disc >= len(variants):
                raise DefmtError(f"discriminant {disc} of {fmt!r}")
            fmt = variants[disc]
        return self._render(fmt, buf)

    def _render(self, fmt: str, buf) -> str:
        parts = self._params(fmt)
        params, auto = [], 0
        for _, p in parts:
            if p is None:
                continue
            m = re.fullmatch(r"(\d*)(?:=([^:]*))?(?::(.*))?", p)
            pos, typ, hint = (m.group(1), m.group(2), m.group(3)) if m else ("", "?", "")
            if pos == "":
                pos, auto = auto, auto + 1
            params.append((int(pos), (typ or "?").strip(), (hint or "").strip()))
        values = {}
        for pos, typ, hint in sorted(params, key=lambda t: t[0]):  # arguments are encoded in argument order
            if pos not in values:
                values[pos] = self._value(typ, hint, buf)
        out, k = "", 0
        for lit, p in parts:
            out += lit
            if p is not None:
                out += values[params[k][0]]
                k += 1
        return out

    def decode(self, frame: bytes) -> dict:
        buf = [bytes(frame), 0]
        try:
            index = self._uint(buf, 2)
            tag, fmt = self.strings.get(index, (None, None))
            if fmt is None:
                raise DefmtError(f"unknown string index {index}")
            ts = self._render(self.timestamp, buf) if self.timestamp else ""
            text = self._render(fmt, buf)
            if buf[1] != len(buf[0]):
                text += f" [+{len(buf[0]) - buf[1]} undecoded bytes]"
            return {"level": tag.replace("defmt_", ""), "timestamp": ts, "text": text}
        except (DefmtError, ValueError, KeyError, IndexError) as e:
            return {"level": "?", "timestamp": "", "text": f"<undecoded defmt frame {frame.hex()}: {e}>"}


# ---------------------------------------------------------------------------------------------------------------
# FPGA frames and bus messages (--frames): docs/fpga-link.md, docs/bus.md, docs/telemetry.md
# ---------------------------------------------------------------------------------------------------------------

def _crc32c_table():
    t = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0x82F6_3B78 if c & 1 else c >> 1
        t.append(c)
    return t


CRC32C_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    c = 0xFFFF_FFFF
    for b in data:
        c = CRC32C_TABLE[(c ^ b) & 0xFF] ^ (c >> 8)
    return c ^ 0xFFFF_FFFF


FPGA_SYNC = bytes([0x1A, 0xCF, 0xFC, 0x1D])


def synth_frames(n: int, decimation: int = 15) -> bytes:
    """n FPGA frames (240 B: sync, seq, decimation, flags, 16 x 7 ADC codes, temperature, CRC-32C): mid-scale
    codes with a small deterministic wobble, board temperature 25.00 C."""
    rng = random.Random(405)
    out = bytearray()
    for seq in range(n):
        f = bytearray(FPGA_SYNC + struct.pack("<HHBB", seq & 0xFFFF, decimation, 0x01, 0))
        f += struct.pack("<112H", *(0x8000 + rng.randint(-8, 8) for _ in range(112)))
        f += struct.pack("<h", 2500)
        f += struct.pack("<I", crc32c(bytes(f)))
        out += f
    return bytes(out)


TELEMETRY_VARIANTS = ["Fused", "Allan", "Health", "Faults", "Ack", "Housekeeping", "Time", "Nav"]


def kiss_frames(data: bytes):
    """The payloads of the KISS frames in a byte string (FEND C0, command byte 00, FESC DB DC/DD)."""
    for raw in data.split(b"\xc0"):
        if len(raw) < 2:
            continue
        out, esc = bytearray(), False
        for b in raw[1:]:
            if esc:
                out.append({0xDC: 0xC0, 0xDD: 0xDB}.get(b, b))
                esc = False
            elif b == 0xDB:
                esc = True
            else:
                out.append(b)
        yield bytes(out)


def decode_bus_message(pkt: bytes, header_len: int = 4) -> dict:
    """CSP v1 packet (4-byte header, CRC-32C trailer when flag 0x01) -> the telemetry variant it carries."""
    info = {"len": len(pkt), "hex": pkt[:48].hex()}
    if len(pkt) < header_len + 4 + 2:
        return info
    flags = pkt[header_len - 1]
    payload = pkt[header_len:-4]  # the KISS link CRC-32C (big-endian) over the payload closes every packet
    info["link_crc_ok"] = crc32c(payload) == int.from_bytes(pkt[-4:], "big")
    body = payload[:-4] if flags & 1 else payload  # end-to-end CRC with the header's CRC flag
    info["version"] = body[0]
    variant = body[1]
    info["kind"] = TELEMETRY_VARIANTS[variant] if variant < len(TELEMETRY_VARIANTS) else f"variant {variant}"
    if variant == 0 and len(body) > 2:  # Fused: seq is the first field, a postcard varint
        v, shift = 0, 0
        for b in body[2:7]:
            v |= (b & 0x7F) << shift
            shift += 7
            if not b & 0x80:
                break
        info["seq"] = v
    return info


# ---------------------------------------------------------------------------------------------------------------
# Peripheral models
# ---------------------------------------------------------------------------------------------------------------

class Periph:
    """A register file: word-addressed, byte/halfword accesses merged; subclasses add behaviour."""

    resets: dict = {}

    def __init__(self, machine, name: str, base: int):
        self.m, self.name, self.base = machine, name, base
        self.regs = dict(self.resets)

    def read(self, off: int, size: int) -> int:
        word = self.read_word(off & ~3) & 0xFFFF_FFFF
        return (word >> (8 * (off & 3))) & ((1 << (8 * size)) - 1)

    def write(self, off: int, size: int, value: int):
        aligned, shift = off & ~3, 8 * (off & 3)
        mask = ((1 << (8 * size)) - 1) << shift
        old = self.regs.get(aligned, 0)
        self.write_word(aligned, (old & ~mask) | ((value << shift) & mask), mask)

    def read_word(self, off: int) -> int:
        return self.regs.get(off, 0)

    def write_word(self, off: int, value: int, mask: int = 0xFFFF_FFFF):
        self.regs[off] = value


class Rcc(Periph):
    CR, PLLCFGR, CFGR, BDCR, CSR = 0x00, 0x04, 0x08, 0x70, 0x74
    resets = {0x00: 0x0000_0083, 0x04: 0x2400_3010, 0x30: 0x0010_0000, 0x50: 0x7E67_91FF, 0x54: 0x0000_00F1,
              0x60: 0x36FE_C9FF, 0x64: 0x0007_5F33, 0x74: 0x0E00_0000, 0x84: 0x2000_3000}
    READY = [(0, 1), (16, 17), (24, 25), (26, 27)]  # (ON bit, RDY bit): HSI, HSE, PLL, PLLI2S

    def _ready(self, sw: int) -> bool:
        cr = self.regs[self.CR]
        return bool(cr & {0: 1 << 1, 1: 1 << 17, 2: 1 << 25}.get(sw, 0))

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        old = self.regs.get(off, 0)
        if off == self.CR:
            sws = (self.regs.get(self.CFGR, 0) >> 2) & 3
            pll_src_hse = self.regs[self.PLLCFGR] & (1 << 22)
            # RM0090 §7.3.1: a clock in use as SYSCLK (directly or through the PLL) cannot be switched off.
            if sws == 2 and old & (1 << 24) and not value & (1 << 24):
                self.m.warn("RCC_CR: PLLON cleared while the PLL is SYSCLK (hardware keeps it on)")
                value |= 1 << 24
            keep_hse = sws == 1 or (sws == 2 and pll_src_hse)
            keep_hsi = sws == 0 or (sws == 2 and not pll_src_hse)
            if keep_hse and old & (1 << 16) and not value & (1 << 16):
                self.m.warn("RCC_CR: HSEON cleared while HSE drives SYSCLK (hardware keeps it on)")
                value |= 1 << 16
            if keep_hsi and old & 1 and not value & 1:
                value |= 1
            for on, rdy in self.READY:
                value = (value | (1 << rdy)) if value & (1 << on) else (value & ~(1 << rdy))
            for bit, what in ((24, "PLLON"), (16, "HSEON")):
                if value & (1 << bit) and not old & (1 << bit):
                    self.m.event(f"rcc_{what.lower()}", f"RCC_CR {what} set")
        elif off == self.PLLCFGR:
            if self.regs[self.CR] & (1 << 24) and value != old:
                self.m.warn("RCC_PLLCFGR written while the PLL is on (hardware ignores it)")
                return
        elif off == self.CFGR:
            sw, old_sws = value & 3, (old >> 2) & 3
            sws = sw if self._ready(sw) else old_sws
            if not self._ready(sw):
                self.m.warn(f"RCC_CFGR: SW={sw} selects a clock that is not ready; SWS stays {old_sws}")
            value = (value & ~0xC) | (sws << 2)
            self.regs[off] = value
            if sws != old_sws or (value ^ old) & 0xFFF0:
                self.m.clock_changed()
            return
        elif off == self.CSR:
            if value & (1 << 24):  # RMVF: clear the reset flags
                value &= 0x00FF_FFFF
                self.m.event("rcc_rmvf", "RCC_CSR RMVF (reset flags cleared)")
            value = (value | 2) if value & 1 else (value & ~2)  # LSIRDY follows LSION
        elif off == self.BDCR:
            value = (value | 2) if value & 1 else (value & ~2)  # LSERDY follows LSEON
        self.regs[off] = value

    def tree(self) -> dict:
        return clock_tree(self.regs[self.CR], self.regs[self.PLLCFGR], self.regs.get(self.CFGR, 0))


class Pwr(Periph):
    resets = {0x00: 0x0000_4000, 0x04: 0x0000_4000}  # VOS scale 1; CSR VOSRDY

    def read_word(self, off):
        v = self.regs.get(off, 0)
        return v | (1 << 14) if off == 0x04 else v


class FlashRegs:
    """The flash interface's state (emu.Sim keeps it in fastblock's C struct instead: same field names)."""

    def __init__(self):
        self.f_acr = self.f_cr = self.f_sr = self.f_optcr = self.f_key = self.f_dead = self.f_busy = 0


class FlashIf(Periph):
    """The flash interface (RM0090 §3.5-3.9) and the flash memory it programs and erases.

    KEYR unlock sequence (a wrong key: locked until reset and a bus error), CR (LOCK write-1-only, writes ignored
    while locked, PG/SER/MER/SNB/PSIZE/STRT/EOPIE/ERRIE), SR (EOP/OPERR/WRPERR/PGAERR/PGPERR/PGSERR write-1-to-
    clear, BSY for `bsy_polls` reads after each operation), ACR (latency event, DCRST/ICRST pulses), OPTCR read-only
    at its reset value (no write protection). The operations themselves, their timing and their log are described
    in the module docstring ("Flash programming and erase"). The registers live in `self.s` (a FlashRegs, or
    emu.Sim's C struct, whose fast path handles the common accesses itself and calls this class for the rest)."""
    ACR, KEYR, OPTKEYR, SR, CR, OPTCR = 0x00, 0x04, 0x08, 0x0C, 0x10, 0x14
    CR_RESET, OPTCR_RESET = 0x8000_0000, 0x0FFF_AAED
    PG, SER, MER, STRT, EOPIE, ERRIE, LOCK = 1, 2, 4, 1 << 16, 1 << 24, 1 << 25, 1 << 31
    EOP, OPERR, WRPERR, PGAERR, PGPERR, PGSERR, BSY = 1, 2, 1 << 4, 1 << 5, 1 << 6, 1 << 7, 1 << 16
    SR_W1C = EOP | OPERR | WRPERR | PGAERR | PGPERR | PGSERR
    KEY1, KEY2 = 0x4567_0123, 0xCDEF_89AB
    ERR_NAMES = {PGSERR: "PGSERR", PGPERR: "PGPERR", PGAERR: "PGAERR", WRPERR: "WRPERR"}

    def __init__(self, machine, name, base, regs=None):
        self.m, self.name, self.base = machine, name, base
        s = self.s = regs if regs is not None else FlashRegs()
        s.f_acr, s.f_cr, s.f_sr, s.f_optcr = 0, self.CR_RESET, 0, self.OPTCR_RESET
        s.f_key = s.f_dead = s.f_busy = 0

    @property
    def regs(self) -> dict:
        """The readable registers as a dict (reports, the wait-state check)."""
        s = self.s
        return {self.ACR: s.f_acr, self.CR: s.f_cr, self.OPTCR: s.f_optcr}

    # -- registers ---------------------------------------------------------------------------------------------
    def read_word(self, off):
        s = self.s
        if off == self.SR:
            v = s.f_sr
            if s.f_busy:
                s.f_busy -= 1
                v |= self.BSY
            return v
        return {self.ACR: s.f_acr, self.CR: s.f_cr, self.OPTCR: s.f_optcr}.get(off, 0)

    def write(self, off, size, value):
        aligned, shift = off & ~3, 8 * (off & 3)
        mask = ((1 << (8 * size)) - 1) << shift
        old = self.read_word(aligned) if aligned != self.SR else 0
        self.write_word(aligned, (old & ~mask) | ((value << shift) & mask), mask)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        m, s = self.m, self.s
        if off == self.KEYR:
            self._key(value)
        elif off == self.SR:
            s.f_sr &= ~(value & self.SR_W1C)
        elif off == self.ACR:
            old = s.f_acr
            if (value ^ old) & 0xF:
                m.event("flash_latency", f"FLASH_ACR LATENCY={value & 0xF}")
            # DCRST/ICRST "can be written only when the cache is disabled" (RM0090 §3.9.1)
            if value & (1 << 12) and value & (1 << 10):
                m.flash_violation("FLASH_ACR DCRST set with DCEN set (the D-cache must be disabled to be reset)")
            if value & (1 << 11) and value & (1 << 9):
                m.flash_violation("FLASH_ACR ICRST set with ICEN set (the I-cache must be disabled to be reset)")
            s.f_acr = value & ~((1 << 11) | (1 << 12))  # ICRST/DCRST: no cache is modelled, read back 0
            m.check_wait_states("FLASH_ACR write")
        elif off == self.CR:
            self._write_cr(value)
        elif off in (self.OPTKEYR, self.OPTCR):
            m.warn(f"FLASH_{'OPTKEYR' if off == self.OPTKEYR else 'OPTCR'} written: option bytes are not modelled "
                   "(read-only at their reset value)")

    def _key(self, value):
        m, s = self.m, self.s
        if not s.f_cr & self.LOCK:
            m.flash_violation(f"FLASH_KEYR written with 0x{value:08x} while FLASH_CR is unlocked")
            return
        if s.f_dead:
            m.flash_violation("FLASH_KEYR written after a wrong unlock sequence (locked until reset)")
            return
        if s.f_key == 0 and value == self.KEY1:
            s.f_key = 1
        elif s.f_key == 1 and value == self.KEY2:
            s.f_cr &= ~self.LOCK
            s.f_key = 0
            m.flash_log["unlocks"] += 1
        else:
            s.f_key, s.f_dead = 0, 1
            m.flash_violation(f"FLASH_KEYR: wrong unlock sequence (0x{value:08x}): FLASH_CR locked until reset, "
                              "bus error")
            m.stop("fault", "FLASH_KEYR: a wrong unlock sequence returns a bus error (RM0090 §3.5.1)")

    def _write_cr(self, value) -> bool:
        """A write of FLASH_CR (STRT as written); False if ignored (locked)."""
        s = self.s
        old = s.f_cr
        s.f_busy = 0  # a CR write while BSY stalls the bus until the operation ends (RM0090 §3.9.7)
        if old & self.LOCK:
            if value & ~self.STRT != old:
                self.m.flash_violation(f"FLASH_CR written (0x{value:08x}) while locked (ignored by hardware)")
            return False
        s.f_cr = value & ~self.STRT  # STRT starts the operation and reads back 0 once it ends
        if value & self.STRT:
            self.start(value)
        return True

    # -- operations --------------------------------------------------------------------------------------------
    def _done(self, errors: int = 0):
        """End of an operation: flags, BSY for the next `bsy_polls` reads of SR (the CPU stalled for the operation
        already: BSY is only there to exercise the firmware's wait loop)."""
        s = self.s
        if errors:
            s.f_sr |= errors
            if s.f_cr & self.ERRIE and errors & (self.PGPERR | self.PGAERR | self.WRPERR):
                s.f_sr |= self.OPERR
        elif s.f_cr & self.EOPIE:
            s.f_sr |= self.EOP
        s.f_busy = 0 if errors else self.m.flash_bsy_polls  # a refused operation does not start

    def _wrp(self, snb: int) -> bool:
        return not (self.s.f_optcr >> 16) & (1 << snb)

    def start(self, cr):
        """STRT: a sector (SER, SNB) or mass (MER) erase."""
        m = self.m
        psize = (cr >> 8) & 3
        if psize == 3:
            m.warn("FLASH_CR PSIZE=x64 needs VPP on the chip's pin (not on this board): erase timed as x32")
        if cr & self.MER:
            sectors = list(range(len(FLASH_SECTORS)))
        elif cr & self.SER:
            snb = (cr >> 3) & 0xF
            if snb >= len(FLASH_SECTORS):
                m.flash_violation(f"FLASH_CR STRT with SNB={snb}: no such sector on the 1 MiB F405")
                self._done(self.WRPERR)
                return
            sectors = [snb]
        else:
            m.flash_violation("FLASH_CR STRT without SER or MER (nothing to erase)")
            return
        if any(self._wrp(n) for n in sectors):
            self._done(self.WRPERR)
            return
        m.flash_erase(sectors, min(psize, 2), bool(cr & self.MER))
        self._done()

    def program(self, off: int, size: int, value: int, old: int) -> int:
        """A store of `value` to flash offset `off` (from 0x0800_0000 or the boot alias) where the flash holds
        `old`: returns what the flash holds after it (the machine makes it so after the store)."""
        m, cr = self.m, self.s.f_cr
        if cr & self.LOCK or not cr & self.PG:
            m.flash_violation(f"write of {size} B (0x{value:0{2 * size}x}) to flash 0x{FLASH_BASE + off:08x} "
                              + ("while FLASH_CR is locked" if cr & self.LOCK else "without FLASH_CR.PG")
                              + ": not programmed, PGSERR")
            self.s.f_sr |= self.PGSERR
            return old
        err = 0
        if size != 1 << ((cr >> 8) & 3):
            err |= self.PGPERR
        if (off & 15) + size > 16:
            err |= self.PGAERR
        sec = flash_sector_of(FLASH_BASE + off)
        if sec is not None and self._wrp(sec[0]):
            err |= self.WRPERR
        if err:
            m.flash_violation(f"write of {size} B to flash 0x{FLASH_BASE + off:08x} with PSIZE=x{8 << ((cr >> 8) & 3)}: "
                              + "|".join(n for b, n in self.ERR_NAMES.items() if err & b) + ", not programmed")
            self._done(err)
            return old
        new = m.flash_program(off, size, value, old)
        self._done()
        return new

    def irq_pending(self) -> bool:
        s = self.s
        return bool((s.f_cr & self.EOPIE and s.f_sr & self.EOP) or (s.f_cr & self.ERRIE and s.f_sr & self.OPERR))


class Usart(Periph):
    SR, DR, BRR, CR1, CR3 = 0x00, 0x04, 0x08, 0x0C, 0x14
    resets = {0x00: 0x0000_00C0}

    def __init__(self, *a):
        super().__init__(*a)
        self.tx = bytearray()  # bytes written to DR (blocking writes)
        self.idle = False  # IDLE: set by the --frames feeder after a burst, cleared by the SR-then-DR read
        self.tx_busy = False  # a DMA transmission in flight: TC clear

    def read_word(self, off):
        if off == self.SR:
            return ((self.regs.get(off, 0) & ~0xF0) | 0x80 | (0 if self.tx_busy else 0x40)
                    | (0x10 if self.idle else 0))  # TXE, TC, IDLE; never RXNE (the DMA takes the bytes)
        if off == self.DR:
            self.idle = False
            return 0
        return self.regs.get(off, 0)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off == self.SR:  # rc_w0
            value = self.regs.get(off, 0) & value
        elif off == self.DR:
            self.tx.append(value & 0xFF)
            return
        self.regs[off] = value

    def irq_pending(self) -> bool:
        cr1 = self.regs.get(self.CR1, 0)
        return bool((cr1 & 0x10 and self.idle) or (cr1 & 0x40 and not self.tx_busy and cr1 & 0x2000))


class Dma(Periph):
    resets = {0x10 + 0x18 * n + 0x14: 0x21 for n in range(8)}  # FCR
    FLAG_SHIFT = (0, 6, 16, 22)  # stream n % 4 in LISR/HISR: FEIF +0, DMEIF +2, TEIF +3, HTIF +4, TCIF +5

    def __init__(self, *a):
        super().__init__(*a)
        self.isr = [0, 0]
        self.ring_len = {}

    def read_word(self, off):
        if off in (0x00, 0x04):
            return self.isr[off >> 2]
        if off in (0x08, 0x0C):  # LIFCR/HIFCR: write-only
            return 0
        return self.regs.get(off, 0)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off in (0x00, 0x04):
            return
        if off in (0x08, 0x0C):  # write 1 to clear
            self.isr[(off - 8) >> 2] &= ~value
            return
        if off >= 0x10 and (off - 0x10) % 0x18 == 0:
            n, old = (off - 0x10) // 0x18, self.regs.get(off, 0)
            if value & 1 and not old & 1:
                self.regs[off] = value
                self.m.event("dma_en", f"{self.name} stream {n} enabled: {self.describe(n, value)}")
                s = self.stream(n)
                if s["dir"] == "P2M" and s["circ"]:
                    self.ring_len[n] = s["ndtr"]
                elif s["dir"] == "M2P":
                    self.start_tx(n, s)
                return
        self.regs[off] = value

    def start_tx(self, n, s):
        """A memory-to-USART transfer: its bytes are captured now (they are in memory), it completes when the
        core next idles (--frames), after the time the line needs."""
        usart = next((p for p in self.m.blocks.values() if isinstance(p, Usart) and p.base + 4 == s["par"]), None)
        if usart is None:
            return
        size = 1 << ((s["cr"] >> 13) & 3)  # MSIZE
        try:
            data = bytes(self.m.uc.mem_read(s["m0ar"], s["ndtr"] * size))
        except UcError:
            self.m.warn(f"{self.name} stream {n}: M0AR 0x{s['m0ar']:08x} unreadable")
            return
        self.m.tx_start(self, n, data, usart)

    def _flag(self, n, bit):
        return (n >> 2, 1 << (self.FLAG_SHIFT[n & 3] + bit))

    def set_flag(self, n, bit):
        i, f = self._flag(n, bit)
        self.isr[i] |= f

    def complete(self, n):
        """End of a normal-mode transfer: NDTR 0, EN cleared, HTIF and TCIF."""
        b = 0x10 + 0x18 * n
        self.regs[b + 4] = 0
        self.regs[b] = self.regs.get(b, 0) & ~1
        self.set_flag(n, 4)
        self.set_flag(n, 5)

    def receive(self, n, data: bytes):
        """Bytes arriving for a circular peripheral-to-memory stream: written at the ring's write position,
        NDTR counts down (and reloads), HTIF/TCIF at the half and the end of the ring."""
        b = 0x10 + 0x18 * n
        length, base = self.ring_len[n], self.regs.get(b + 0xC, 0)
        for byte in data:
            ndtr = self.regs.get(b + 4, 0) or length
            pos = length - ndtr
            self.m.uc.mem_write(base + pos, bytes([byte]))
            ndtr -= 1
            if ndtr == length // 2:
                self.set_flag(n, 4)
            if ndtr == 0:
                self.set_flag(n, 5)
                ndtr = length
            self.regs[b + 4] = ndtr

    def irq_pending(self, n) -> bool:
        cr = self.regs.get(0x10 + 0x18 * n, 0)
        i, _ = self._flag(n, 0)
        flags = self.isr[i] >> self.FLAG_SHIFT[n & 3]
        return bool((cr & 0x10 and flags & 0x20) or (cr & 0x08 and flags & 0x10) or (cr & 0x04 and flags & 0x08))

    def stream(self, n: int) -> dict:
        b = 0x10 + 0x18 * n
        cr = self.regs.get(b, 0)
        return {"cr": cr, "en": bool(cr & 1), "circ": bool(cr & (1 << 8)), "dir": ["P2M", "M2P", "M2M", "?"][(cr >> 6) & 3],
                "channel": (cr >> 25) & 7, "minc": bool(cr & (1 << 10)), "ndtr": self.regs.get(b + 4, 0) & 0xFFFF,
                "par": self.regs.get(b + 8, 0), "m0ar": self.regs.get(b + 0xC, 0)}

    def describe(self, n, cr=None):
        s = self.stream(n)
        return (f"ch{s['channel']} {s['dir']}{' circular' if s['circ'] else ''} NDTR={s['ndtr']} "
                f"PAR=0x{s['par']:08x} M0AR=0x{s['m0ar']:08x}")


class Timer(Periph):
    CR1, SR, EGR, CNT, PSC, ARR = 0x00, 0x10, 0x14, 0x24, 0x28, 0x2C

    def __init__(self, machine, name, base):
        self.bits = 32 if name in TIMERS_32BIT else 16
        self.resets = {self.ARR: (1 << self.bits) - 1}
        super().__init__(machine, name, base)
        self.cnt0, self.t0 = 0, 0.0

    def clock(self) -> float:
        t = self.m.rcc.tree()
        return t["tim_apb1"] if self.name in TIMERS_APB1 else t["tim_apb2"]

    def count(self) -> int:
        if not self.regs.get(self.CR1, 0) & 1:
            return self.cnt0
        rate = self.clock() / (self.regs.get(self.PSC, 0) + 1)
        ticks = int((self.m.now() - self.t0) * rate)
        arr = self.regs.get(self.ARR, 0) or ((1 << self.bits) - 1)
        return (self.cnt0 + ticks) % (arr + 1)

    def rebase(self):
        self.cnt0, self.t0 = self.count(), self.m.now()

    last_eval = None

    def update_flags(self):
        """Compare matches (CCRx) and overflow (UIF) since the last evaluation (only while counting up, --frames)."""
        if not self.regs.get(self.CR1, 0) & 1:
            self.last_eval = None
            return
        arr = self.regs.get(self.ARR, 0) or ((1 << self.bits) - 1)
        rate = self.clock() / (self.regs.get(self.PSC, 0) + 1)
        now = self.m.now()
        if self.last_eval is None:
            self.last_eval = (self.count(), now)
            return
        c0, t0 = self.last_eval
        ticks = int((now - t0) * rate)
        if ticks <= 0:
            return
        c1 = (c0 + ticks) % (arr + 1)
        sr = self.regs.get(self.SR, 0)
        if c0 + ticks > arr:
            sr |= 1  # UIF
        for ch in range(4):
            ccmr = self.regs.get(0x18 + 4 * (ch >> 1), 0)
            if (ccmr >> (8 * (ch & 1))) & 3:  # CCxS != 0: an input channel (capture): no edges here
                continue
            ccr = self.regs.get(0x34 + 4 * ch, 0)
            if ticks > arr or (c0 < ccr <= c0 + ticks) or (c0 + ticks > arr and ccr <= c1):
                sr |= 1 << (ch + 1)
        self.regs[self.SR] = sr
        self.last_eval = (c1, t0 + ticks / rate)

    def irq_pending(self) -> bool:
        return bool(self.regs.get(0x0C, 0) & self.regs.get(self.SR, 0) & 0x1F)

    def read_word(self, off):
        if off == self.CNT:
            return self.count()
        return self.regs.get(off, 0)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off == self.CNT:
            self.cnt0, self.t0 = value & ((1 << self.bits) - 1), self.m.now()
            return
        if off in (self.CR1, self.PSC, self.ARR):
            self.rebase()
        if off == self.SR:  # rc_w0
            value &= self.regs.get(off, 0)
        if off == self.EGR:
            if value & 1:  # UG: counter reset
                self.cnt0, self.t0 = 0, self.m.now()
            return
        self.regs[off] = value


class Iwdg(Periph):
    KR, PR, RLR, SR = 0x00, 0x04, 0x08, 0x0C
    resets = {0x08: 0xFFF}
    KEYS = {0x5555: "unlock", 0xCCCC: "start", 0xAAAA: "reload"}

    def __init__(self, *a):
        super().__init__(*a)
        self.unlocked = False
        self.keys = []  # (key, insn, t)

    def read_word(self, off):
        return 0 if off in (self.KR, self.SR) else self.regs.get(off, 0)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off == self.KR:
            key = value & 0xFFFF
            self.keys.append((key, self.m.insns, self.m.now()))
            self.unlocked = key == 0x5555
            if key == 0xCCCC and not any(k == 0xCCCC for k, _, _ in self.keys[:-1]):
                self.m.event("iwdg_start", "IWDG_KR 0xCCCC (watchdog started)")
            elif key not in self.KEYS:
                self.m.warn(f"IWDG_KR written with 0x{key:04x} (not a key)")
            return
        if off in (self.PR, self.RLR):
            if not self.unlocked:
                self.m.warn(f"IWDG_{'PR' if off == self.PR else 'RLR'} written while locked (ignored by hardware)")
                return
        self.regs[off] = value

    def timeout_s(self) -> float:
        pr = min(self.regs.get(self.PR, 0) & 7, 6)
        return ((self.regs.get(self.RLR, 0xFFF) & 0xFFF) + 1) * (4 << pr) / LSI_HZ


class Adc(Periph):
    """ADC1 (0x000), ADC2 (0x100), ADC3 (0x200), common (0x300) in one 1 KiB block."""

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        unit, reg = off & 0x300, off & 0xFF
        if unit != 0x300 and reg == 0x00:  # SR rc_w0
            value &= self.regs.get(off, 0)
        elif unit != 0x300 and reg == 0x08 and value & (1 << 30):  # CR2 SWSTART: conversion starts and ends
            value &= ~(1 << 30)
            self.regs[unit] = self.regs.get(unit, 0) | 0x12  # STRT|EOC
            self.m.adc_conversions += 1
        self.regs[off] = value

    def read_word(self, off):
        unit, reg = off & 0x300, off & 0xFF
        if unit != 0x300 and reg == 0x4C:  # DR: reading clears EOC
            self.regs[unit] = self.regs.get(unit, 0) & ~0x2
            ch = self.regs.get(unit + 0x34, 0) & 0x1F
            return {16: TS_CAL1 + 30, 17: VREFINT_CAL, 18: 1200}.get(ch, 2048)
        return self.regs.get(off, 0)


class Gpio(Periph):
    MODER, IDR, ODR, BSRR = 0x00, 0x10, 0x14, 0x18
    RESETS = {"A": {0x00: 0xA800_0000, 0x0C: 0x6400_0000}, "B": {0x00: 0x0000_0280, 0x08: 0x0000_00C0,
                                                                  0x0C: 0x0000_0100}}

    def __init__(self, machine, name, base):
        self.resets = self.RESETS.get(name[-1], {})
        super().__init__(machine, name, base)

    def read_word(self, off):
        if off == self.IDR:
            moder, odr = self.regs.get(self.MODER, 0), self.regs.get(self.ODR, 0)
            outs = sum(1 << i for i in range(16) if (moder >> (2 * i)) & 3 == 1)
            return odr & outs
        if off == self.BSRR:
            return 0
        return self.regs.get(off, 0)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        if off == self.BSRR:
            odr = self.regs.get(self.ODR, 0)
            odr = (odr | (value & 0xFFFF)) & ~((value >> 16) & ~value & 0xFFFF)
            self.regs[self.ODR] = odr
            return
        self.regs[off] = value


class Ppb(Periph):
    """System control space, DWT, DBGMCU, NVIC. Offsets relative to 0xE000_0000."""
    DWT_CTRL, DWT_CYCCNT = 0x1000, 0x1004
    VTOR, AIRCR, CPACR, DEMCR, STIR = 0xED08, 0xED0C, 0xED88, 0xEDFC, 0xEF00
    resets = {0x1000: 0x4000_0000, 0xE004: 0x2, 0xED00: 0x410F_C241, 0xED14: 0x0000_0200, 0xED90: 0x0000_0800,
              0xEF34: 0xC000_0000, 0x4_2000: 0x1007_6413, 0xE01C: 0x4000_0000 | (21_000 - 1)}

    def __init__(self, *a):
        super().__init__(*a)
        self.enabled = [0] * 8
        self.pending = [0] * 8
        self.cyc0, self.cyc_insn = 0, 0

    def read_word(self, off):
        if off == self.DWT_CYCCNT:
            if self.regs.get(self.DWT_CTRL, 0) & 1:
                return (self.cyc0 + self.m.insns - self.cyc_insn) & 0xFFFF_FFFF
            return self.cyc0
        if 0xE100 <= off < 0xE120 or 0xE180 <= off < 0xE1A0:
            return self.enabled[(off & 0x1F) >> 2]
        if 0xE200 <= off < 0xE220 or 0xE280 <= off < 0xE2A0:
            return self.pending[(off & 0x1F) >> 2]
        if off == self.AIRCR:
            return 0xFA05_0000 | (self.regs.get(off, 0) & 0x700)
        return self.regs.get(off, 0)

    def write_word(self, off, value, mask=0xFFFF_FFFF):
        i = (off & 0x1F) >> 2
        if 0xE100 <= off < 0xE120:
            self.enabled[i] |= value
        elif 0xE180 <= off < 0xE1A0:
            self.enabled[i] &= ~value
        elif 0xE200 <= off < 0xE220:
            self.pending[i] |= value
        elif 0xE280 <= off < 0xE2A0:
            self.pending[i] &= ~value
        elif off == self.STIR:
            self.pending[(value & 0x1FF) >> 5] |= 1 << (value & 31)
        elif off == self.DWT_CYCCNT:
            self.cyc0, self.cyc_insn = value, self.m.insns
        elif off == self.DWT_CTRL:
            if value & 1 and not self.regs.get(off, 0) & 1:
                self.cyc_insn = self.m.insns
            self.regs[off] = value
        elif off == self.AIRCR:
            if value >> 16 == 0x05FA:
                self.regs[off] = value & 0x700
                if value & 0x4:
                    self.m.stop("reset", "SCB AIRCR SYSRESETREQ (a software reset: SCB::sys_reset, e.g. from the "
                                         "panic or HardFault handler)")
            else:
                self.m.warn("SCB_AIRCR written without VECTKEY 0x05FA (ignored by hardware)")
        elif off == self.VTOR:
            self.regs[off] = value & 0x3FFF_FF80  # TBLOFF, bits 29:7
            self.m.vtor_written(self.regs[off])
        elif off == self.CPACR:
            self.regs[off] = value
            self.m.event("cpacr", f"SCB CPACR = 0x{value:08x}")
        else:
            self.regs[off] = value

    def irq_enabled(self):
        return [n for n in range(256) if self.enabled[n >> 5] >> (n & 31) & 1]

    def irq_priority(self, n):
        word = self.regs.get(0xE400 + (n & ~3), 0)
        return (word >> (8 * (n & 3))) & 0xFF


# ---------------------------------------------------------------------------------------------------------------
# The machine
# ---------------------------------------------------------------------------------------------------------------

class Machine:
    def __init__(self, img: Image, args):
        self.img, self.args = img, args
        self.insns = 0
        self.t_base, self.insn_base, self.hz = 0.0, 0, float(HSI_HZ)
        self.events, self.warnings = [], []
        self.stop_kind, self.stop_msg = None, None
        self.event_flag = False
        self.sev_count = self.wfe_wakeups = 0
        self.adc_conversions = 0
        self.min_sp, self.min_sp_at = img.stack_start, None
        self.last_block = (0, 0)
        self.polled = collections.Counter()
        self.binfo = {}  # block address -> (size, instructions, may move SP down)
        self.hist = collections.Counter()
        self.mmio_reads = collections.Counter()
        self.prev_hist, self.prev_mmio = collections.Counter(), collections.Counter()
        self.touched = {}  # block name -> first access (insn, pc, r/w, addr)
        self.unknown_blocks = []
        self.trap = {}
        self.wait_state_violations = []
        self.idle = False
        self.flash_timing = FLASH_TIMING[getattr(args, "flash_timing", None) or "max"]
        self.flash_bsy_polls = getattr(args, "flash_bsy_polls", None)
        self.flash_bsy_polls = 1 if self.flash_bsy_polls is None else self.flash_bsy_polls
        self.flash_log = {"erases": [], "unlocks": 0, "programs": 0, "bytes_programmed": 0, "overprograms": 0, "program_s": 0.0,
                          "erase_s": 0.0, "violations": [], "violation_count": 0}

        self.irq_counts = collections.Counter()
        self.tx_inflight, self.tx_log, self.bus_msgs = [], [], []
        self.first_fused, self.frames_result, self.frames_fed, self.fused = None, None, 0, []
        uc = self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M4)
        self._map_memory()
        self._map_peripherals()
        self._sources = self.irq_sources()
        self._install_hooks()

    # -- time and logging --------------------------------------------------------------------------------------
    def now(self) -> float:
        """Virtual seconds since reset: instructions at the HCLK of the moment, 1 IPC."""
        return self.t_base + (self.insns - self.insn_base) / self.hz

    def clock_changed(self):
        self.t_base, self.insn_base = self.now(), self.insns
        t = self.rcc.tree()
        self.hz = t["hclk"] or float(HSI_HZ)
        self.event("clock", f"SYSCLK {t['sysclk_source']} {mhz(t['sysclk'])}, HCLK {mhz(t['hclk'])}, "
                            f"PCLK1 {mhz(t['pclk1'])}, PCLK2 {mhz(t['pclk2'])}")
        self.check_wait_states("clock switch")

    def check_wait_states(self, what):
        """RM0090 table 10 (2.7-3.6 V): HCLK <= 30 MHz x (LATENCY+1)."""
        hclk = self.rcc.tree()["hclk"]
        ws = self.flash.regs.get(0, 0) & 0xF
        if hclk > 30e6 * (ws + 1):
            v = f"{what}: HCLK {mhz(hclk)} with LATENCY={ws} (needs >= {int((hclk - 1) // 30e6)})"
            self.wait_state_violations.append(v)
            self.warn(v)

    def pc(self) -> int:
        return self.uc.reg_read(UC_ARM_REG_PC)

    def event(self, kind, text):
        self.events.append({"kind": kind, "insn": self.insns, "t_us": round(self.now() * 1e6, 2),
                            "pc": self.last_block[0], "text": text})
        if self.args.verbose:
            print(f"  [{self.insns:>10,} insns {self.now() * 1e3:9.3f} ms] {text}  @{self.img.where(self.last_block[0])}")

    def warn(self, text):
        if len(self.warnings) < 200 and text not in (w["text"] for w in self.warnings[-20:]):
            self.warnings.append({"insn": self.insns, "pc": self.last_block[0], "text": text})
            if self.args.verbose:
                print(f"  WARNING: {text} @{self.img.where(self.last_block[0])}")

    def stop(self, kind, msg):
        if self.stop_kind is None:
            self.stop_kind, self.stop_msg = kind, msg
        self.uc.emu_stop()

    # -- flash programming and erase (FlashIf decides; these do it) --------------------------------------------
    def flash_violation(self, text):
        """Something the firmware did that the flash interface refuses or that the chip does not do as meant."""
        log = self.flash_log
        log["violation_count"] += 1
        if len(log["violations"]) < 200:
            log["violations"].append({"insn": self.insns, "t_us": round(self.now() * 1e6, 2),
                                      "pc": self.last_block[0], "text": text})
        self.warn(f"flash: {text}")

    def flash_summary(self) -> dict:
        """The run's flash activity: erases (sector, start, duration), word programs, violations."""
        log = self.flash_log
        return {"erases": log["erases"], "erase_count": len(log["erases"]), "erase_s": round(log["erase_s"], 6),
                "unlocks": log["unlocks"], "programs": log["programs"], "bytes_programmed": log["bytes_programmed"],
                "program_s": round(log["program_s"], 6), "overprograms": log["overprograms"],
                "violation_count": log["violation_count"], "violations": log["violations"],
                "timing": {v: k for k, v in FLASH_TIMING.items()}[self.flash_timing],
                "bsy_polls": self.flash_bsy_polls}

    def flash_stall(self, seconds: float, erase: bool = False) -> float:
        """The flash is busy for `seconds`: the CPU stalls (single bank: every fetch from flash waits), virtual time
        moves on for the timers and the watchdog. Returns the time that passed (Sim: less when the IWDG resets the
        chip during an erase)."""
        self.skip_time(seconds)
        return seconds

    def flash_program(self, off: int, size: int, value: int, old: int) -> int:
        """Programs `size` bytes at flash offset `off`: a program can only clear bits (RM0090 §3.6.2: 'successive
        write operations are possible without the need of an erase operation when changing bits from 1 to 0').
        Returns the new contents."""
        log = self.flash_log
        new = old & value
        if new != value:
            log["overprograms"] += 1
            self.flash_violation(f"program of 0x{value:0{2 * size}x} over 0x{old:0{2 * size}x} at "
                                 f"0x{FLASH_BASE + off:08x} (not erased): the flash holds 0x{new:0{2 * size}x}")
        log["programs"] += 1
        log["bytes_programmed"] += size
        log["program_s"] += self.flash_stall(FLASH_PROGRAM_S[self.flash_timing])
        return new

    def flash_erase(self, sectors, psize: int, mass: bool):
        t, log = self.flash_timing, self.flash_log
        d = FLASH_MASS_ERASE_S[psize][t] if mass else sum(FLASH_ERASE_S[FLASH_SECTORS[s][1]][psize][t]
                                                              for s in sectors)
        t0 = self.now()
        done = self.flash_stall(d, erase=True)
        cut = done < d - 1e-12
        rng = random.Random(int(t0 * 1e6))
        for s in sectors:
            start, size = FLASH_SECTORS[s]
            off = start - FLASH_BASE
            if cut:  # a reset during the erase: the sector's contents are undefined (garbage here)
                self.flash_mem[off:off + size] = rng.randbytes(size)
            else:
                ctypes.memset(ctypes.addressof(self.flash_buf) + off, ERASED, size)
            self.code_changed(off, size)
        what = "mass erase" if mass else f"sector {sectors[0]}"
        log["erases"].append({"sectors": list(sectors), "mass": mass, "t_s": round(t0, 6), "duration_s": round(done, 6),
                              "psize": f"x{8 << psize}", "cut": cut, "insn": self.insns})
        log["erase_s"] += done
        self.event("flash_erase", f"flash {what} at x{8 << psize}: {done * 1e3:.0f} ms"
                   + (f" (cut short by a reset after {done * 1e3:.0f} of {d * 1e3:.0f} ms: contents undefined)"
                      if cut else ""))

    def code_changed(self, off: int, size: int):
        """Flash changed under code unicorn may have translated: drop those translations (both mappings)."""
        self.uc.ctl_remove_cache(FLASH_BASE + off, FLASH_BASE + off + size)
        self.uc.ctl_remove_cache(off, off + size)

    _flash_fix = None  # (offset, size, value): what the flash must hold once the store being hooked is done

    def flash_sync(self):
        """Applies the pending fix-up: the store hook runs before the store, which writes its raw value."""
        fix = self._flash_fix
        if fix is not None:
            self._flash_fix = None
            off, size, value = fix
            self.flash_mem[off:off + size] = value.to_bytes(size, "little")

    def _on_flash_write(self, uc, access, addr, size, value, _):
        """A store to flash memory (both mappings are writable RAM to unicorn): the flash interface decides what
        the flash holds afterwards; when that is not the value stored, a fix-up restores it right after the store
        (at the next block, flash interface access, flash store or stop, whichever comes first)."""
        if addr >= FLASH_BASE:
            off = addr - FLASH_BASE
        elif addr < FLASH_SIZE:
            off = addr
        else:
            return
        self.flash_sync()
        value &= (1 << (8 * size)) - 1
        old = int.from_bytes(self.flash_mem[off:off + size], "little")
        new = self.flash.program(off, size, value, old)
        if new != value:
            self._flash_fix = (off, size, new)

    # -- memory ------------------------------------------------------------------------------------------------
    def _map_memory(self):
        uc, img = self.uc, self.img
        rng = random.Random(0xF405)
        # flash: one host buffer mapped at 0x0800_0000 and at the boot alias 0 (BOOT0 = 0), so that both see every
        # program and erase; read/execute only, a store is a program attempt (`_on_flash_write`)
        self.flash_buf = (ctypes.c_ubyte * FLASH_SIZE)()
        ctypes.memset(self.flash_buf, ERASED, FLASH_SIZE)
        self.flash_mem = memoryview(self.flash_buf).cast("B")
        sram = bytearray(rng.getrandbits(8) for _ in range(SRAM_SIZE))  # power-on garbage
        ccm = bytearray(rng.getrandbits(8) for _ in range(CCM_SIZE))
        for paddr, vaddr, data, memsz in img.segments:
            if FLASH_BASE <= paddr < FLASH_BASE + FLASH_SIZE:
                if paddr + len(data) > FLASH_BASE + FLASH_SIZE:
                    raise ToolError(f"boot.py: a segment at 0x{paddr:08x} ({len(data)} B) runs past the flash")
                self.flash_mem[paddr - FLASH_BASE:paddr - FLASH_BASE + len(data)] = data
            elif SRAM_BASE <= paddr < SRAM_BASE + SRAM_SIZE and data:
                raise ToolError(f"boot.py: a segment loads into SRAM at 0x{paddr:08x} (no flash image?)")
            elif not (SRAM_BASE <= paddr < SRAM_BASE + SRAM_SIZE or CCM_BASE <= paddr < CCM_BASE + CCM_SIZE):
                raise ToolError(f"boot.py: segment at 0x{paddr:08x} is outside the F405's memories")
        # paint the stack region
        lo, hi = img.stack_end - SRAM_BASE, img.stack_start - SRAM_BASE
        if not (0 <= lo <= hi <= SRAM_SIZE):
            raise ToolError(f"boot.py: stack [0x{img.stack_end:08x}, 0x{img.stack_start:08x}) is not in SRAM")
        sram[lo:hi] = struct.pack("<I", STACK_PAINT) * ((hi - lo) // 4)
        self.flash_image = self.flash_mem  # live: what the flash holds now
        self.flash_at_reset = bytes(self.flash_mem)
        # writable to unicorn: a store reaches the memory after the store hook, which decides what it holds (a
        # write-protected mapping with a "handled" UC_HOOK_MEM_WRITE_PROT still stores, through a stale TLB entry)
        uc.mem_map_ptr(FLASH_BASE, FLASH_SIZE, UC_PROT_ALL, self.flash_buf)
        uc.mem_map_ptr(0, FLASH_SIZE, UC_PROT_ALL, self.flash_buf)
        self._flash_store_hook()
        uc.mem_map(SRAM_BASE, SRAM_SIZE, UC_PROT_ALL)
        uc.mem_write(SRAM_BASE, bytes(sram))
        uc.mem_map(CCM_BASE, CCM_SIZE, UC_PROT_READ | UC_PROT_WRITE)
        uc.mem_write(CCM_BASE, bytes(ccm))
        self.ccm_at_reset = bytes(ccm)
        # system memory: the bootloader pages as plain read-only memory, the last page through MMIO so that
        # 0x1FFF_7A30.. faults like the rest of the reserved space.
        sysmem = bytearray([ERASED]) * (0x8000)
        uid = bytes.fromhex("3200 2f00 0551 3437 3033 3932")  # a made-up unique ID
        sysmem[UID_ADDR - SYSMEM_BASE:UID_ADDR - SYSMEM_BASE + 12] = uid
        struct.pack_into("<H", sysmem, FLASH_SIZE_ADDR - SYSMEM_BASE, FLASH_SIZE >> 10)
        struct.pack_into("<HHH", sysmem, VREFINT_CAL_ADDR - SYSMEM_BASE, VREFINT_CAL, TS_CAL1, TS_CAL2)
        self.sysmem = bytes(sysmem)
        uc.mem_map(SYSMEM_BASE, 0x7000, UC_PROT_READ)
        uc.mem_write(SYSMEM_BASE, self.sysmem[:0x7000])
        uc.mmio_map(SYSMEM_BASE + 0x7000, 0x1000, self._sysmem_read, None, self._sysmem_write, None)

    def _flash_store_hook(self):
        self.uc.hook_add(unicorn.UC_HOOK_MEM_WRITE, self._on_flash_write, begin=0, end=FLASH_BASE + FLASH_SIZE - 1)

    def _sysmem_read(self, uc, off, size, _):
        addr = SYSMEM_BASE + 0x7000 + off
        if addr + size > SYSMEM_END:
            self.stop("fault", f"read of reserved address 0x{addr:08x} (past system memory/OTP; BusFault on the chip)"
                               f" near {self.img.where(self.last_block[0])}")
            return 0
        return int.from_bytes(self.sysmem[addr - SYSMEM_BASE:addr - SYSMEM_BASE + size], "little")

    def _sysmem_write(self, uc, off, size, value, _):
        addr = SYSMEM_BASE + 0x7000 + off
        self._fault_access("write", addr, size, value)

    # -- peripherals -------------------------------------------------------------------------------------------
    def _map_peripherals(self):
        self.blocks = {}
        kinds = {"RCC": Rcc, "PWR": Pwr, "FLASH": FlashIf, "USART1": Usart, "USART2": Usart, "USART3": Usart,
                 "USART6": Usart, "DMA1": Dma, "DMA2": Dma, "IWDG": Iwdg, "ADC": Adc}
        for name, base in PERIPHERALS.items():
            cls = kinds.get(name) or (Timer if name in TIMERS_APB1 | TIMERS_APB2 else
                                      Gpio if name.startswith("GPIO") else Periph)
            self.blocks[base] = cls(self, name, base)
        self.rcc, self.flash = self.blocks[PERIPHERALS["RCC"]], self.blocks[PERIPHERALS["FLASH"]]
        self.ppb = Ppb(self, "PPB", PPB_BASE)
        self.block_starts = sorted(self.blocks)
        self._map_windows()

    def _map_windows(self):
        """The MMIO windows; the flash interface's 1 KiB gets its own (a lean path: a program or erase touches it
        about ten times per word)."""
        fl = PERIPHERALS["FLASH"]
        for base, size in PERIPH_WINDOWS:
            if base <= fl < base + size:
                self.uc.mmio_map(base, fl - base, self._periph_read, base, self._periph_write, base)
                self.uc.mmio_map(fl, 0x400, self._flash_read, None, self._flash_write, None)
                rest = fl + 0x400
                self.uc.mmio_map(rest, base + size - rest, self._periph_read, rest, self._periph_write, rest)
            else:
                self.uc.mmio_map(base, size, self._periph_read, base, self._periph_write, base)
        self.uc.mmio_map(PPB_BASE, PPB_SIZE, self._ppb_read, None, self._ppb_write, None)

    def _flash_read(self, uc, off, size, _):
        self.flash_sync()
        p = self.flash
        if "FLASH" not in self.touched:
            self._touch(p, "read", p.base + off)
        v = p.read(off, size)
        if self.args.trace_mmio:
            print(f"    R{size} 0x{p.base + off:08x} FLASH+0x{off:03x} -> 0x{v:08x}")
        return v

    def _flash_write(self, uc, off, size, value, _):
        self.flash_sync()
        p = self.flash
        if "FLASH" not in self.touched:
            self._touch(p, "write", p.base + off, value)
        self.last_read = None
        if self.args.trace_mmio:
            print(f"    W{size} 0x{p.base + off:08x} FLASH+0x{off:03x} <- 0x{value:08x}")
        p.write(off, size, value)

    def _block(self, addr):
        i = bisect.bisect_right(self.block_starts, addr) - 1
        if i >= 0:
            base = self.block_starts[i]
            p = self.blocks[base]
            if addr < base + BLOCK_SIZE.get(p.name, 0x400):
                return p
        base = addr & ~0x3FF
        p = Periph(self, f"unknown@0x{base:08x}", base)
        self.blocks[base] = p
        self.block_starts = sorted(self.blocks)
        self.unknown_blocks.append(base)
        self.warn(f"access to 0x{addr:08x}: no peripheral there on the F405 (reserved; a BusFault on the chip)")
        return p

    def _touch(self, p, rw, addr, value=None):
        if p.name not in self.touched:
            self.touched[p.name] = {"insn": self.insns, "pc": self.last_block[0], "access": rw, "addr": addr}
            if self.args.verbose:
                print(f"  first access to {p.name}: {rw} 0x{addr:08x} @{self.img.where(self.last_block[0])}")

    def _spin_check(self, key, p):
        """The same register read with the same value, over and over, with no write in between: a busy-wait on
        something that will never change in this model (or on the chip)."""
        if key == self.last_read:
            self.same_reads += 1
            if self.same_reads == self.args.spin_limit:
                addr, v = key
                self.stop("stuck", f"{self.same_reads:,} identical reads of {p.name}+0x{addr - p.base:03x} "
                                   f"(0x{addr:08x}) = 0x{v:08x} with no peripheral write in between")
        else:
            self.last_read, self.same_reads = key, 0

    last_read, same_reads = None, 0

    def _periph_read(self, uc, off, size, window):
        addr = window + off
        p = self._block(addr)
        self._touch(p, "read", addr)
        v = p.read(addr - p.base, size)
        self.mmio_reads[(addr, v)] += 1
        self._spin_check((addr, v), p)
        if self.args.trace_mmio:
            print(f"    R{size} 0x{addr:08x} {p.name}+0x{addr - p.base:03x} -> 0x{v:08x}")
        return v

    def _periph_write(self, uc, off, size, value, window):
        addr = window + off
        p = self._block(addr)
        self._touch(p, "write", addr, value)
        self.last_read = None
        if self.args.trace_mmio:
            print(f"    W{size} 0x{addr:08x} {p.name}+0x{addr - p.base:03x} <- 0x{value:08x}")
        p.write(addr - p.base, size, value)

    def _ppb_read(self, uc, off, size, _):
        v = self.ppb.read(off, size)
        self.mmio_reads[(PPB_BASE + off, v)] += 1
        self._spin_check((PPB_BASE + off, v), self.ppb)
        return v

    def _ppb_write(self, uc, off, size, value, _):
        self.last_read = None
        self.ppb.write(off, size, value)

    # -- hooks -------------------------------------------------------------------------------------------------
    def _install_hooks(self):
        uc = self.uc
        self.log, self._frame = [], None
        self._symbol_hooks()
        uc.hook_add(UC_HOOK_BLOCK, self._on_block)
        uc.hook_add(UC_HOOK_MEM_INVALID, self._on_mem_invalid)
        self._code_hooks()

    def _parts(self):
        """The ELF(s) whose code is in flash (one, or an ImageSet's active ones)."""
        return getattr(self.img, "active", None) or [self.img]

    def _symbol_hooks(self):
        """Traps (fault/panic handlers) and the defmt hooks of the ELF(s) in flash."""
        names = ["", "", "NMI", "HardFault", "MemManage", "BusFault", "UsageFault", "", "", "", "", "SVCall",
                 "DebugMonitor", "", "PendSV", "SysTick"]
        self.trap, self.special = {}, {}
        self.defmt = None
        for part in self._parts():
            vt = part.vector_table - FLASH_BASE
            vec = struct.unpack_from("<16I", self.flash_mem, vt) if 0 <= vt <= FLASH_SIZE - 64 else (0,) * 16
            for name, what in (("DefaultHandler", "DefaultHandler (an unexpected exception or interrupt)"),
                               ("DefaultHandler_", "DefaultHandler (an unexpected exception or interrupt)"),
                               ("HardFault", "the HardFault handler"), ("_HardFault", "the HardFault handler"),
                               ("HardFaultTrampoline", "the HardFault trampoline"),
                               ("__rustc::rust_begin_unwind", "the panic handler (rust_begin_unwind)"),
                               ("rust_begin_unwind", "the panic handler (rust_begin_unwind)"),
                               ("_defmt_panic", "defmt's panic (defmt::panic!/unwrap!/assert!)"),
                               ("core::panicking::panic_fmt", "core::panicking::panic_fmt (a panic)")):
                a = part.addr_of.get(name)
                if a:
                    self.trap.setdefault(a & ~1, what)
            # the fault and system handlers of the vector table (SVCall, PendSV, SysTick are legitimate if used)
            for i in (2, 3, 4, 5, 6, 12):
                if vec[i] and vec[i] != 0xFFFF_FFFF:
                    self.trap.setdefault(vec[i] & ~1, f"the {names[i]} handler ({part.func_at(vec[i])[0]})")
            for a, _, n, _ in part.funcs:
                if n.endswith("__cortex_m_rt_HardFault"):
                    self.trap.setdefault(a, "the HardFault handler")
            # defmt: collect the raw frames (acquire .. write* .. release) and decode them (each ELF its strings)
            dec = Defmt(part)
            self.defmt = self.defmt or dec
            for name, fn in (("_defmt_acquire", lambda uc, d=dec: self._on_defmt_acquire(uc, d)),
                             ("_defmt_write", self._on_defmt_write), ("_defmt_release", self._on_defmt_release)):
                a = part.addr_of.get(name)
                if a:
                    self.special[a & ~1] = fn

    def _code_hooks(self):
        """SEV and WFI: a code hook at each (again when the code in flash changes)."""
        for h in getattr(self, "_code_hook_handles", []):
            self.uc.hook_del(h)
        self._code_hook_handles = [self.uc.hook_add(UC_HOOK_CODE, self._on_sev, begin=a, end=a)
                                   for a in sorted(self.img.sev)]
        self._code_hook_handles += [self.uc.hook_add(UC_HOOK_CODE, self._on_wfi, begin=a, end=a)
                                    for a in sorted(self.img.wfi)]

    # -- the code in flash changes (the bootloader swaps an image in and jumps to it) ---------------------------
    def vtor_written(self, vtor: int):
        self.event("vtor", f"SCB VTOR = 0x{vtor:08x}")
        self.reidentify()
        if isinstance(self.img, ImageSet) and FLASH_BASE < vtor < FLASH_BASE + FLASH_SIZE and not any(
                im.vector_table == vtor for im in self.img.active):
            self.warn(f"VTOR 0x{vtor:08x}: no given ELF's vector table is there in flash now")

    def reidentify(self):
        """Which of the given ELFs are in flash now (ImageSet only); the hooks follow when that changed."""
        if isinstance(self.img, ImageSet) and self.img.identify(self.flash_mem):
            self.event("images", "code in flash: " + (", ".join(im.label() for im in self.img.active)
                                                      or "none of the given ELFs"))
            self._images_changed()

    def _images_changed(self):
        self.binfo.clear()
        self.polled.clear()
        self._symbol_hooks()
        self._code_hooks()

    def boot_vector(self):
        """(initial SP, reset PC, VTOR) at reset: the vector table at 0 (the boot alias of 0x0800_0000). When that
        is erased and the ELF's vector table is elsewhere (an application linked behind a bootloader, run without
        it), the ELF's, with VTOR pointing at it as the bootloader leaves it ("direct boot")."""
        sp, pc = struct.unpack_from("<2I", self.flash_mem, 0)
        vt = self.img.vector_table
        if pc == 0xFFFF_FFFF and FLASH_BASE < vt <= FLASH_BASE + FLASH_SIZE - 8:
            sp, pc = struct.unpack_from("<2I", self.flash_mem, vt - FLASH_BASE)
            return sp, pc, vt
        return sp, pc, 0

    def vectors(self, n: int):
        """The first n entries of the vector table VTOR points at."""
        vtor = self.ppb.regs.get(Ppb.VTOR, 0)
        try:
            return struct.unpack(f"<{n}I", bytes(self.uc.mem_read(vtor, 4 * n)))
        except UcError:
            return (0,) * n

    def _on_block(self, uc, addr, size, _):
        """Every translation block: count, sample, and check SP after each block that may have moved it down."""
        if self._flash_fix is not None:
            self.flash_sync()
        if self.insns >= self._slice_insn:  # the host-time slice (see _emulate)
            self._slice_insn = self.insns + 100_000
            if time.monotonic() >= self.slice_end:
                self.uc.emu_stop()  # before this block runs: it runs, and is counted, on resume
                return
        info = self.binfo.get(addr)
        if info is None or info[0] != size:
            info = self.binfo[addr] = (size, *self.img.block_info(addr, size))
        self.last_block = (addr, size)
        self.insns += info[1]
        self.hist[addr] += 1
        if self.check_sp:
            sp = uc.reg_read(UC_ARM_REG_SP)
            if sp < self.min_sp:
                self.min_sp, self.min_sp_at = sp, addr
            if sp < self.img.stack_end or sp > self.img.stack_start:
                self._overflow(sp, addr, self.prev_block)
                return
        self.check_sp = info[2]
        self.prev_block = (addr, size)
        if addr in self.trap:
            lr = uc.reg_read(UC_ARM_REG_LR)
            self.stop("trap", f"reached {self.trap[addr]} at 0x{addr:08x}, called from {self.img.where(lr & ~1)}"
                      + (f"; last log line: {self.log[-1]['text']!r}" if self.log else ""))
            return
        if addr in self.special:
            self.special[addr](uc)
        if addr in self.img.task_polls:
            self.polled[addr] += 1
        if self.insns > self.insn_limit:
            self.stop("budget", f"instruction budget exhausted ({self.insn_limit:,} instructions)")

    prev_block = (0, 0)
    check_sp = True
    slice_end, _slice_insn = float("inf"), 0

    def _overflow(self, sp, addr, culprit_block):
        img = self.img
        side = (f"below _stack_end 0x{img.stack_end:08x} by {img.stack_end - sp} B" if sp < img.stack_end
                else f"above _stack_start 0x{img.stack_start:08x}")
        culprits = img.sp_writers(*culprit_block) if culprit_block[1] else []

        def size_of(t):
            m = re.search(r"#(\d+)$", t)
            return int(m.group(1)) if m and t.startswith("sub") else 0

        if culprits:  # the biggest explicit frame in the block that moved SP out
            ca, ct = max(culprits, key=lambda c: size_of(c[1]))
            others = [t for a, t in culprits if a != ca]
            cause = f"after `{ct}` at {img.where(ca)}" + (f" (with {'; '.join(others)})" if others else "")
        else:
            ca, ct = culprit_block[0], None
            cause = f"in the block at {img.where(culprit_block[0])}"
        self.overflow = {"sp": sp, "pc": addr, "culprit_pc": ca, "culprit_insn": ct, "function": img.func_at(ca)[0]}
        self.stop("stack-overflow", f"STACK OVERFLOW: SP=0x{sp:08x} {side} (stack region "
                                    f"{img.stack_start - img.stack_end} B) {cause}; PC now {img.where(addr)}")

    overflow = None

    def reached(self, func_start: int) -> bool:
        return func_start in self.binfo

    def _fault_access(self, kind, addr, size, value=None):
        sp = self.uc.reg_read(UC_ARM_REG_SP)
        pc = self.pc()
        if sp < self.img.stack_end or sp > self.img.stack_start:
            self._overflow(sp, pc, self.last_block)
            self.stop_msg += f"; faulting {kind} of {size} B at 0x{addr:08x}"
            return
        region = ("flash (not writable outside programming)" if FLASH_BASE <= addr < FLASH_BASE + FLASH_SIZE
                  else "system memory (read only)" if SYSMEM_BASE <= addr < SYSMEM_END else "an unmapped address")
        self.stop("fault", f"FAULT: {kind} of {size} B at 0x{addr:08x} ({region}) by {self.img.where(pc)} "
                           f"(SP=0x{sp:08x}, LR=0x{self.uc.reg_read(UC_ARM_REG_LR):08x})")

    def _on_mem_invalid(self, uc, access, addr, size, value, _):
        kind = {ucc.UC_MEM_READ_UNMAPPED: "read", ucc.UC_MEM_WRITE_UNMAPPED: "write",
                ucc.UC_MEM_FETCH_UNMAPPED: "instruction fetch", ucc.UC_MEM_WRITE_PROT: "write",
                ucc.UC_MEM_READ_PROT: "read", ucc.UC_MEM_FETCH_PROT: "instruction fetch"}.get(access, "access")
        self._fault_access(kind, addr, size, value)
        return False

    def _on_defmt_acquire(self, uc, decoder=None):
        if decoder is not None:
            self.defmt = decoder
        self._frame = bytearray()

    def _on_defmt_write(self, uc):
        if self._frame is None:
            self._frame = bytearray()
        ptr, n = uc.reg_read(unicorn.arm_const.UC_ARM_REG_R0), uc.reg_read(unicorn.arm_const.UC_ARM_REG_R1)
        if 0 < n < 4096:
            try:
                self._frame += uc.mem_read(ptr, n)
            except UcError:
                pass

    def _on_defmt_release(self, uc):
        if self._frame:
            entry = self.defmt.decode(self._frame)
            entry.update(insn=self.insns, t_us=round(self.now() * 1e6, 2))
            self.log.append(entry)
            if self.args.verbose:
                print(f"  defmt {entry['level']:5} {entry['timestamp']} {entry['text']}")
        self._frame = None

    def _on_sev(self, uc, addr, size, _):
        self.event_flag = True
        self.sev_count += 1

    def _on_wfi(self, uc, addr, size, _):
        self.stop("wfi", f"WFI at {self.img.where(addr)}")

    # -- run ---------------------------------------------------------------------------------------------------
    def run(self, timeout_s: float, max_insns: int):
        """Reset, then run to the executor's first idle (or a failure)."""
        uc = self.uc
        self.insn_limit = max_insns
        sp, pc, vtor = self.boot_vector()
        vec = (sp, pc)
        if vtor:
            self.ppb.regs[Ppb.VTOR] = vtor
            self.event("direct_boot", f"0x0800_0000 erased: started from the vector table at 0x{vtor:08x} "
                                      "(VTOR set there, as a bootloader would)")
        uc.reg_write(UC_ARM_REG_SP, vec[0])
        self.initial_sp, self.reset_pc = vec[0], vec[1]
        self.deadline = time.monotonic() + timeout_s
        self.timeout_s = timeout_s
        t0 = time.monotonic()
        if self._emulate(vec[1]) == "idle":
            self.stop_kind = "idle"
        self.host_s = time.monotonic() - t0
        self.boot_insns, self.boot_s = self.insns, self.now()
        self.boot_sev, self.boot_wfe = self.sev_count, self.wfe_wakeups

    UNTIL = FLASH_BASE + FLASH_SIZE - 2  # erased flash: never executed

    def _emulate(self, pc: int) -> str:
        """Runs from pc until the core would sleep ("idle": WFE with no event), an exception return of an
        interrupt we delivered ("exc-return"), or a failure ("stop": stop_kind/stop_msg say which)."""
        uc, img = self.uc, self.img
        slice_s = 0.25
        while True:
            remaining = self.deadline - time.monotonic()
            if remaining <= 0:
                self.stop_kind = "timeout"
                self.stop_msg = f"host-time budget exhausted ({self.timeout_s:g} s)"
                break
            self.prev_hist, self.hist = self.hist, collections.Counter()
            self.prev_mmio, self.mmio_reads = self.mmio_reads, collections.Counter()
            err = None
            # the slice ends at a block's start (_on_block); unicorn's timeout is only a backstop: it stops inside an
            # instruction, which then runs again on resume with its MMIO or flash side effects repeated
            self.slice_end, self._slice_insn = time.monotonic() + min(slice_s, remaining), 0
            try:
                uc.emu_start(pc | 1, self.UNTIL, timeout=int((remaining + 5.0) * 1e6))
            except UcError as e:
                err = e
            self.flash_sync()
            pc = self.pc()
            if self.stop_kind:
                break
            if err is not None:
                if err.errno == ucc.UC_ERR_INSN_INVALID and (pc in img.wfe or pc - 2 in img.wfe):
                    wfe_at = pc if pc in img.wfe else pc - 2
                    self.insns += 1
                    if self.event_flag:  # the event register was set: WFE returns at once
                        self.event_flag = False
                        self.wfe_wakeups += 1
                        pc = wfe_at + 2
                        continue
                    self.idle, self.idle_pc = True, wfe_at
                    self.stop_msg = f"idle: WFE at {img.where(wfe_at)} with no event pending"
                    return "idle"
                if err.errno == ucc.UC_ERR_EXCEPTION and pc >= 0xFFFF_FFE0 and self.exc_depth:
                    return "exc-return"
                insn = img.insn_text.get(pc & ~1, "?")
                self.stop_kind = "fault"
                self.stop_msg = (f"FAULT: {err} at {img.where(pc)} (`{insn}`; SP=0x{uc.reg_read(UC_ARM_REG_SP):08x}, "
                                 f"LR=0x{uc.reg_read(UC_ARM_REG_LR):08x})")
                break
            if pc == self.UNTIL:
                self.stop_kind, self.stop_msg = "fault", "execution reached erased flash"
                break
            # a time slice ended: keep going (the histogram of this slice is kept for a "stuck" report)
        if self.stop_kind in ("timeout", "budget", "stuck") and not self.stop_msg.startswith("STUCK"):
            hist = self.hist + self.prev_hist
            mmio = self.mmio_reads + self.prev_mmio
            tops = ", ".join(f"{img.where(a)} x{n}" for a, n in hist.most_common(5))
            polls = ", ".join(f"0x{a:08x}={v:#x} x{n}" for (a, v), n in mmio.most_common(3))
            self.stop_msg = (f"STUCK at {img.where(pc)}: {self.stop_msg}. Hottest blocks: {tops}"
                             + (f". Most-read registers: {polls}" if polls else ""))
        return "stop"

    exc_depth = 0

    # -- interrupts (used by --frames only) --------------------------------------------------------------------
    def irq_sources(self):
        """(IRQ number, peripheral, stream or None) for the interrupt sources modelled as level-triggered."""
        out = []
        for name, irq in (("USART1", 37), ("USART2", 38), ("USART3", 39), ("USART6", 71), ("TIM2", 28),
                          ("TIM3", 29), ("TIM4", 30), ("TIM5", 50)):
            out.append((irq, self.blocks[PERIPHERALS[name]], None))
        for n, irq in enumerate((11, 12, 13, 14, 15, 16, 17, 47)):
            out.append((irq, self.blocks[PERIPHERALS["DMA1"]], n))
        for n, irq in enumerate((56, 57, 58, 59, 60, 68, 69, 70)):
            out.append((irq, self.blocks[PERIPHERALS["DMA2"]], n))
        out.append((4, self.flash, None))  # FLASH: EOP with EOPIE, OPERR with ERRIE
        return out

    def pending_irqs(self):
        pend = set()
        for irq, p, n in self._sources:
            if isinstance(p, Timer):
                p.update_flags()
            if p.irq_pending(n) if n is not None else p.irq_pending():
                pend.add(irq)
        for i in range(8):  # software-pended (ISPR/STIR)
            for b in range(32):
                if self.ppb.pending[i] >> b & 1:
                    pend.add(32 * i + b)
        return sorted(n for n in pend if self.ppb.enabled[n >> 5] >> (n & 31) & 1)

    def deliver(self, irq: int) -> bool:
        """Exception entry (the frame pushed on MSP, LR = EXC_RETURN), the handler run to its return, then the
        interrupted context restored. False if the run stopped."""
        uc = self.uc
        handler = self.vectors(16 + irq + 1)[16 + irq]
        if not handler or handler == 0xFFFF_FFFF:
            self.stop("fault", f"IRQ {irq} ({IRQ_NAMES.get(irq)}) has no vector")
            return False
        self.ppb.pending[irq >> 5] &= ~(1 << (irq & 31))
        ctx = uc.context_save()
        sp = uc.reg_read(UC_ARM_REG_SP)
        # extended frame (FPCCR.ASPEN/LSPEN at reset: the FP registers are reserved once the thread used the FPU)
        frame = 26 * 4
        new_sp = (sp - frame) & ~7
        regs = [uc.reg_read(r) for r in (unicorn.arm_const.UC_ARM_REG_R0, unicorn.arm_const.UC_ARM_REG_R1,
                                           unicorn.arm_const.UC_ARM_REG_R2, unicorn.arm_const.UC_ARM_REG_R3,
                                           unicorn.arm_const.UC_ARM_REG_R12, UC_ARM_REG_LR)]
        ret = self.resume_pc
        try:
            uc.mem_write(new_sp, struct.pack("<8I", *regs, ret, 0x0100_0000))
        except UcError:
            self._overflow(new_sp, handler & ~1, self.last_block)
            return False
        if new_sp < self.img.stack_end:
            self._overflow(new_sp, handler & ~1, (0, 0))
            return False
        uc.reg_write(UC_ARM_REG_SP, new_sp)
        self.min_sp = min(self.min_sp, new_sp)
        uc.reg_write(UC_ARM_REG_LR, 0xFFFF_FFE9)
        self.exc_depth += 1
        self.irq_counts[irq] += 1
        r = self._emulate(handler & ~1)
        self.exc_depth -= 1
        if r != "exc-return":
            if r == "idle":
                self.stop("fault", f"WFE inside the {IRQ_NAMES.get(irq)} handler")
            return False
        uc.context_restore(ctx)
        self.event_flag = True  # an exception return sets the event register
        return True

    def service_interrupts(self) -> bool:
        for _ in range(200):
            pend = self.pending_irqs()
            if not pend:
                return True
            if not self.deliver(pend[0]):
                return False
        self.stop("stuck", f"interrupt storm: IRQ {pend[0]} ({IRQ_NAMES.get(pend[0])}) still pending after 200 "
                           "deliveries (its handler does not clear its source)")
        return False

    def skip_time(self, seconds: float):
        """The core sleeps: virtual time moves on without instructions."""
        if seconds > 0:
            self.t_base += seconds

    # -- the FPGA frame stream (--frames) ----------------------------------------------------------------------
    def tx_start(self, dma, n, data: bytes, usart):
        baud = usart_baud(self.rcc.tree()["pclk2" if usart.name in ("USART1", "USART6") else "pclk1"],
                          usart.regs.get(Usart.BRR, 0), usart.regs.get(Usart.CR1, 0)) or 115_200
        usart.tx_busy = True
        self.tx_inflight.append((dma, n, usart, bytes(data), self.now() + len(data) * 10 / baud))

    def tx_complete_all(self) -> bool:
        if not self.tx_inflight:
            return False
        for dma, n, usart, data, t_done in self.tx_inflight:
            self.skip_time(t_done - self.now())
            dma.complete(n)
            usart.tx_busy = False
            self.tx_log.append({"usart": usart.name, "t_us": round(self.now() * 1e6, 1), "bytes": data.hex()})
            if usart.name == "USART2":
                self.on_bus_frame(data)
        self.tx_inflight = []
        return True

    def on_bus_frame(self, data: bytes):
        for msg in kiss_frames(data):
            info = decode_bus_message(msg)
            info["t_us"] = round(self.now() * 1e6, 1)
            self.bus_msgs.append(info)
            if info.get("kind") == "Fused":
                self.fused.append(info)
                if self.first_fused is None:
                    self.first_fused = info

    def frames_phase(self, stream: bytes, frame_hz: float, max_frames: int, want_fused: int = 1):
        """Feeds the FPGA byte stream into USART1's RX DMA ring (one frame per burst, then IDLE), delivers the
        interrupts the peripherals raise, completes DMA transmissions, until the first `Fused` report leaves on
        the bus (USART2 TX DMA) or the input ends."""
        dma2, u1 = self.blocks[PERIPHERALS["DMA2"]], self.blocks[PERIPHERALS["USART1"]]
        s = dma2.stream(2)
        ring_len = dma2.ring_len.get(2)
        if not (s["en"] and s["circ"] and ring_len):
            self.frames_result = "USART1 RX DMA ring (DMA2 stream 2) is not running"
            return
        self.frames_fed = 0
        self.boot_stop = (self.stop_kind, self.stop_msg)
        self.stop_kind = None
        pos = 0
        chunk = 240
        self.deadline = time.monotonic() + self.timeout_s
        t0 = time.monotonic()
        while len(self.fused) < want_fused:
            self.resume_pc = self.idle_pc + 2
            if not self.service_interrupts():
                break
            r = self._emulate(self.idle_pc + 2)
            if r != "idle":
                if r == "exc-return":
                    self.stop("fault", "exception return without an exception")
                break
            if self.tx_complete_all():
                continue
            if pos >= len(stream) or self.frames_fed >= max_frames:
                break
            part = stream[pos:pos + chunk]
            pos += len(part)
            self.skip_time(1.0 / frame_hz)
            dma2.receive(2, part)
            u1.idle = True
            self.frames_fed += 1
        self.frames_stop = (self.stop_kind, self.stop_msg) if self.stop_kind else None
        self.frames_host_s = time.monotonic() - t0
        self.frames_insns = self.insns - self.boot_insns
        if self.first_fused:
            self.frames_result = (f"first Fused report (seq {self.first_fused.get('seq')}) left on USART2 at "
                                  f"{self.first_fused['t_us'] / 1e3:.3f} ms; {len(self.fused)} Fused after "
                                  f"{self.frames_fed} frames")
        else:
            self.frames_result = (f"no Fused report after {self.frames_fed} frames: "
                                  + (self.stop_msg if self.frames_stop else "input ended or frame limit reached"))
        self.stop_kind, self.stop_msg = self.boot_stop

    # -- results -----------------------------------------------------------------------------------------------
    def stack_hwm(self):
        lo, hi = self.img.stack_end, self.img.stack_start
        data = self.uc.mem_read(lo, hi - lo)
        pattern = struct.pack("<I", STACK_PAINT)
        deepest = hi
        for off in range(0, hi - lo, 4):
            if data[off:off + 4] != pattern:
                deepest = lo + off
                break
        return hi - deepest, hi - max(min(self.min_sp, hi), lo)


# ---------------------------------------------------------------------------------------------------------------
# Assertions and report
# ---------------------------------------------------------------------------------------------------------------

def check(m: Machine, args) -> tuple[list, dict]:
    img, results, fig = m.img, [], {}

    clean = m.stop_kind == "idle"

    def res(name, ok, measured, expected="", detail="", at_idle=True):
        """at_idle: a check of the state at idle, skipped (and failed) when the boot did not get there."""
        skipped = at_idle and not clean
        results.append({"name": name, "ok": bool(ok) and not skipped, "skipped": skipped, "measured": measured,
                        "expected": expected, "detail": detail})

    res("boot reaches idle without fault", clean, m.stop_msg, "executor idle at WFE", at_idle=False)
    res("no stack overflow", m.overflow is None,
        "none" if m.overflow is None else f"SP=0x{m.overflow['sp']:08x} in {m.overflow['function']}",
        f"SP within [0x{img.stack_end:08x}, 0x{img.stack_start:08x}]", at_idle=False)

    # tasks
    expected = img.task_polls
    ran = [expected[a] for a in expected if m.polled[a]]
    missing = [expected[a] for a in expected if not m.polled[a]]
    fig["tasks"] = {"expected": len(expected), "polled": sorted(ran), "not_polled": sorted(missing),
                    "polls": {expected[a]: m.polled[a] for a in expected}}
    res("every task polled before idle", clean and not missing and expected, f"{len(ran)}/{len(expected)}",
        f"{len(expected)} TaskStorage::poll functions in the ELF", "not polled: " + ", ".join(missing) if missing else "",
        at_idle=False)

    # stack
    region = img.stack_start - img.stack_end
    painted, by_sp = m.stack_hwm()
    hwm = max(painted, by_sp)
    pct = 100.0 * hwm / region if region else 100.0
    fig["stack"] = {"region_bytes": region, "stack_end": img.stack_end, "stack_start": img.stack_start,
                    "painted_hwm_bytes": painted, "sp_hwm_bytes": by_sp, "hwm_bytes": hwm, "hwm_percent": round(pct, 1),
                    "min_sp": m.min_sp, "min_sp_at": img.where(m.min_sp_at) if m.min_sp_at else None,
                    "initial_sp": m.initial_sp}
    res("stack high-water mark", m.overflow is None and pct <= args.max_stack_percent,
        f"{hwm} B = {pct:.1f} % of {region} B (painted {painted} B, lowest SP {by_sp} B"
        + (f" at {img.where(m.min_sp_at)}" if m.min_sp_at else "") + ")", f"<= {args.max_stack_percent:g} %",
        at_idle=False)

    # IWDG
    iw = m.blocks[PERIPHERALS["IWDG"]]
    start = next(((i, t) for k, i, t in iw.keys if k == 0xCCCC), None)
    pll = next((e for e in m.events if e["kind"] == "rcc_pllon"), None)
    fig["iwdg"] = {"keys": [{"key": f"0x{k:04x}", "insn": i, "t_us": round(t * 1e6, 2)} for k, i, t in iw.keys[:20]],
                   "started": start is not None, "start_insn": start[0] if start else None,
                   "start_t_us": round(start[1] * 1e6, 2) if start else None,
                   "first_pllon_insn": pll["insn"] if pll else None, "first_pllon_t_us": pll["t_us"] if pll else None,
                   "pr": iw.regs.get(4, 0), "rlr": iw.regs.get(8, 0xFFF), "timeout_s_at_32khz": round(iw.timeout_s(), 3),
                   "reloads": sum(1 for k, _, _ in iw.keys if k == 0xAAAA)}
    if start and pll:
        rel = "BEFORE" if start[0] < pll["insn"] else "AFTER"
        when = (f"{rel} clock init: start at insn {start[0]:,} ({start[1] * 1e3:.3f} ms), first PLLON at insn "
                f"{pll['insn']:,} ({pll['t_us'] / 1e3:.3f} ms)")
    elif start:
        when = f"started at insn {start[0]:,} ({start[1] * 1e3:.3f} ms); no PLLON write seen"
    else:
        when = "never started (no 0xCCCC written to IWDG_KR)"
    fig["iwdg"]["when"] = when
    res("IWDG started", start is not None, when + f"; timeout {iw.timeout_s():.2f} s at LSI 32 kHz "
        f"(PR={iw.regs.get(4, 0)}, RLR={iw.regs.get(8, 0xFFF)})", "KR <- 0xCCCC")
    if args.require_iwdg_before_clock:
        res("IWDG started before clock init", bool(start and (not pll or start[0] < pll["insn"])), when,
            "0xCCCC before the first PLLON write")

    # flash accelerator
    acr = m.flash.regs.get(0, 0)
    lat, prft, ic, dc = acr & 0xF, bool(acr & (1 << 8)), bool(acr & (1 << 9)), bool(acr & (1 << 10))
    fig["flash_acr"] = {"value": acr, "latency": lat, "prften": prft, "icen": ic, "dcen": dc,
                        "wait_state_violations": m.wait_state_violations}
    res("flash accelerator on, 5 wait states", prft and ic and dc and lat == EXPECT["latency"],
        f"ACR=0x{acr:08x}: LATENCY={lat} PRFTEN={int(prft)} ICEN={int(ic)} DCEN={int(dc)}",
        "LATENCY=5, PRFTEN=ICEN=DCEN=1")
    res("flash wait states sufficient at every clock change", not m.wait_state_violations,
        "; ".join(m.wait_state_violations) or "ok", "HCLK <= 30 MHz x (LATENCY+1)")
    fl = fig["flash"] = m.flash_summary()
    res("flash interface used as RM0090 says (no write without PG, none while locked, no refused operation)",
        not fl["violation_count"], f"{fl['violation_count']} violation(s)"
        + (": " + "; ".join(v["text"] for v in fl["violations"][:3]) if fl["violation_count"] else
           f"; {fl['erase_count']} erase(s), {fl['programs']} program(s)"), "none", at_idle=False)

    # clocks
    rcc = m.rcc
    cr, pllcfgr, cfgr = rcc.regs[Rcc.CR], rcc.regs[Rcc.PLLCFGR], rcc.regs.get(Rcc.CFGR, 0)
    t = rcc.tree()
    pf = pll_fields(pllcfgr)
    fig["clocks"] = {"rcc_cr": cr, "rcc_pllcfgr": pllcfgr, "rcc_cfgr": cfgr, **{k: v for k, v in t.items()},
                     "pll": pf}
    pll_ok = (pf["src"] == "HSE" and pf["m"] == EXPECT["pllm"] and pf["n"] == EXPECT["plln"]
              and pf["p"] == EXPECT["pllp"] and pf["q"] == EXPECT["pllq"])
    res("PLL: HSE 8 MHz /4 x168 /2, Q /7", pll_ok,
        f"PLLCFGR=0x{pllcfgr:08x}: src {pf['src']} M={pf['m']} N={pf['n']} P=/{pf['p']} Q=/{pf['q']} -> VCO in "
        f"{mhz(t['pll_vco_in'])}, VCO {mhz(t['pll_vco'])}, P {mhz(t['pll_p'])}, Q {mhz(t['pll48'])}",
        "src HSE M=4 N=168 P=/2 Q=/7")
    sw, sws = cfgr & 3, (cfgr >> 2) & 3
    cfg_ok = (sw == 2 and sws == 2 and t["ahb_div"] == 1 and t["apb1_div"] == 4 and t["apb2_div"] == 2)
    res("CFGR: SYSCLK=PLL, AHB /1, APB1 /4, APB2 /2", cfg_ok,
        f"CFGR=0x{cfgr:08x}: SW={sw} SWS={sws} AHB /{t['ahb_div']} APB1 /{t['apb1_div']} APB2 /{t['apb2_div']}",
        "SW=SWS=2 (PLL), HPRE /1, PPRE1 /4, PPRE2 /2")
    freqs = {k: t[k] for k in ("sysclk", "hclk", "pclk1", "pclk2", "pll48")}
    res("derived frequencies", all(abs(freqs[k] - EXPECT[k]) < 1 for k in freqs),
        ", ".join(f"{k.upper()} {mhz(v)}" for k, v in freqs.items()),
        ", ".join(f"{k.upper()} {mhz(EXPECT[k])}" for k in freqs))
    res("VCO within limits (input 1-2 MHz, output 100-432 MHz)",
        0.95e6 <= t["pll_vco_in"] <= 2.1e6 and 100e6 <= t["pll_vco"] <= 432e6,
        f"VCO in {mhz(t['pll_vco_in'])}, out {mhz(t['pll_vco'])}", "RM0090 §7.3.2")

    # USARTs
    fig["usart"] = {}
    for name, pclk_key, want in (("USART1", "pclk2", EXPECT["usart1_baud"]), ("USART2", "pclk1", EXPECT["usart2_baud"])):
        u = m.blocks[PERIPHERALS[name]]
        brr, cr1, cr3 = u.regs.get(Usart.BRR, 0), u.regs.get(Usart.CR1, 0), u.regs.get(Usart.CR3, 0)
        baud = usart_baud(t[pclk_key], brr, cr1)
        err = (baud - want) / want * 100 if want else 0
        fig["usart"][name] = {"brr": brr, "cr1": cr1, "cr3": cr3, "over8": bool(cr1 & (1 << 15)), "pclk": t[pclk_key],
                              "baud": baud, "error_percent": round(err, 3), "ue": bool(cr1 & (1 << 13)),
                              "te": bool(cr1 & 8), "re": bool(cr1 & 4), "dmar": bool(cr3 & 0x40),
                              "dmat": bool(cr3 & 0x80), "tx_bytes_polled": u.tx.hex()}
        ok = abs(err) <= 1.0 and cr1 & (1 << 13) and cr1 & 0xC == 0xC
        res(f"{name} {want:,} baud", ok,
            f"{t[pclk_key] / 1e6:g} MHz / BRR 0x{brr:x} (OVER8={int(bool(cr1 & (1 << 15)))}) = {baud:,.0f} baud "
            f"({err:+.2f} %), UE={int(bool(cr1 & (1 << 13)))} TE={int(bool(cr1 & 8))} RE={int(bool(cr1 & 4))} "
            f"DMAR={int(bool(cr3 & 0x40))}", f"{want:,} baud +-1 %, UE TE RE")

    # RX DMA rings
    fig["dma"] = {}
    for ctl, n, ch, periph in EXPECT["rx_dma"]:
        d = m.blocks[PERIPHERALS[ctl]]
        s = d.stream(n)
        fig["dma"][f"{ctl}_S{n}"] = s
        dr = PERIPHERALS[periph] + 4
        m0_sym = img.func_at(s["m0ar"])[0]
        buf_ok = SRAM_BASE <= s["m0ar"] and s["m0ar"] + max(s["ndtr"], 1) <= SRAM_BASE + SRAM_SIZE and not (
            img.stack_end <= s["m0ar"] < img.stack_start)
        ok = s["en"] and s["circ"] and s["channel"] == ch and s["dir"] == "P2M" and s["par"] == dr and buf_ok
        res(f"{ctl} stream {n}: {periph} RX ring", ok,
            f"EN={int(s['en'])} CIRC={int(s['circ'])} ch{s['channel']} {s['dir']} PAR=0x{s['par']:08x} "
            f"M0AR=0x{s['m0ar']:08x} NDTR={s['ndtr']}",
            f"EN CIRC ch{ch} P2M PAR={periph}_DR 0x{dr:08x}, buffer in SRAM (DMA cannot reach CCM), not in the stack")

    # FPU enable
    cpacr = m.ppb.regs.get(Ppb.CPACR, 0)
    res("FPU enabled (CPACR CP10/CP11 full access)", (cpacr >> 20) & 0xF == 0xF, f"CPACR=0x{cpacr:08x}",
        "bits 23:20 = 0xF (unicorn runs VFP code regardless: this is the only FPU check)")

    # NOLOAD statics in CCM: cortex-m-rt neither zeroes nor initialises them; every word must have been written
    ccm_lo, ccm_n = img.sections.get(".ccmram", (CCM_BASE, 0))
    if ccm_n:
        now = bytes(m.uc.mem_read(ccm_lo, ccm_n))
        before = m.ccm_at_reset[ccm_lo - CCM_BASE:ccm_lo - CCM_BASE + ccm_n]
        stale = [ccm_lo + o for o in range(0, ccm_n - 3, 4) if now[o:o + 4] == before[o:o + 4]]
        where = collections.Counter(img.data_symbol(a) for a in stale)
        fig["ccm_noload"] = {"bytes": ccm_n, "stale_words": len(stale), "stale_by_symbol": dict(where),
                             "first_stale": [f"0x{a:08x}" for a in stale[:16]]}
        res(".ccmram (NOLOAD) initialised before idle", not stale,
            f"{ccm_n} B, {len(stale)} words still hold their power-on garbage"
            + (": " + ", ".join(f"{k} x{v}" for k, v in where.most_common(5)) if stale else ""),
            "every word written (CCM is neither zeroed nor loaded at reset)")

    # informational figures
    vec = m.vectors(16 + 82)
    default = img.addr_of.get("DefaultHandler")
    fig["nvic_enabled"] = [{"irq": n, "name": IRQ_NAMES.get(n, "?"), "priority": m.ppb.irq_priority(n),
                            "handler": img.func_at(vec[16 + n])[0] if n < 82 and vec[16 + n] else None,
                            "default_handler": n < 82 and default is not None and vec[16 + n] & ~1 == default & ~1}
                           for n in m.ppb.irq_enabled()]
    fig["gpio"] = {n: {"moder": m.blocks[PERIPHERALS[n]].regs.get(0, 0), "odr": m.blocks[PERIPHERALS[n]].regs.get(0x14, 0)}
                   for n in ("GPIOA", "GPIOC")}
    fig["adc_conversions"] = m.adc_conversions
    fig["reset_flags_csr_at_idle"] = rcc.regs.get(Rcc.CSR, 0)
    return results, fig


def check_frames(m: Machine, args, results, fig):
    """The --frames phase: the data path from the FPGA ring to the bus, with interrupts delivered."""
    region = m.img.stack_start - m.img.stack_end
    painted, by_sp = m.stack_hwm()
    hwm = max(painted, by_sp)
    pct = 100.0 * hwm / region
    fig["frames"] = {"result": m.frames_result, "fed": m.frames_fed, "first_fused": m.first_fused,
                     "fused": [{"seq": f.get("seq"), "t_us": f["t_us"], "link_crc_ok": f.get("link_crc_ok")}
                               for f in m.fused],
                     "bus_messages": m.bus_msgs[:50], "tx": m.tx_log[:50],
                     "irqs_delivered": {IRQ_NAMES.get(k, str(k)): v for k, v in sorted(m.irq_counts.items())},
                     "stack_hwm_bytes": hwm, "stack_hwm_percent": round(pct, 1),
                     "instructions": getattr(m, "frames_insns", 0),
                     "instructions_per_frame": round(getattr(m, "frames_insns", 0) / m.frames_fed) if m.frames_fed else None,
                     "host_s": round(getattr(m, "frames_host_s", 0.0), 2),
                     "stop": getattr(m, "frames_stop", None)}
    ok_run = m.frames_result is not None and getattr(m, "frames_stop", None) is None
    results.append({"name": "frames: no fault while streaming", "ok": ok_run, "skipped": False,
                    "measured": (m.frames_stop[1] if getattr(m, "frames_stop", None) else
                                 m.frames_result or "boot did not reach idle"), "expected": "", "detail": ""})
    results.append({"name": "frames: Fused reports on the bus (USART2 TX DMA)", "ok": len(m.fused) >= args.fused,
                    "skipped": False, "measured": m.frames_result or "not run", "expected": f"{args.fused} KISS/CSP frame(s) carrying "
                    "Telemetry::Fused", "detail": ""})
    results.append({"name": "frames: stack high-water mark (boot + streaming + interrupt frames)",
                    "ok": ok_run and pct <= args.max_stack_percent, "skipped": False,
                    "measured": f"{hwm} B = {pct:.1f} % of {region} B", "expected": f"<= {args.max_stack_percent:g} %",
                    "detail": ""})


def report(m: Machine, img: Image, results, fig, args):
    run = {"elf": img.path, "sha256": img.sha256, "mtime": time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(img.mtime)),
           "stop": m.stop_kind, "message": m.stop_msg, "instructions": m.boot_insns,
           "virtual_ms": round(m.boot_s * 1e3, 3), "host_s": round(m.host_s, 2), "sev": m.boot_sev,
           "wfe_wakeups": m.boot_wfe, "peripherals_touched": sorted(m.touched),
           "unknown_blocks": [f"0x{b:08x}" for b in m.unknown_blocks]}
    frames = img.static_frames()
    fig["static_frames"] = [{"function": n, "addr": a, "sub_sp": s, "reached": m.reached(a),
                             "exceeds_stack": s >= img.stack_start - img.stack_end} for a, n, s in frames]
    out = {"run": run, "figures": fig, "assertions": results, "events": m.events, "warnings": m.warnings,
           "passed": all(r["ok"] for r in results)}

    print(f"boot.py: {img.path}  (built {run['mtime']}, sha256 {img.sha256[:12]})")
    print(f"  stack [0x{img.stack_end:08x}, 0x{img.stack_start:08x}) = {img.stack_start - img.stack_end} B, "
          f"initial SP 0x{m.initial_sp:08x}, reset 0x{m.reset_pc:08x}; {len(img.task_polls)} task poll functions")
    print(f"  run: {m.stop_msg}")
    print(f"       {m.boot_insns:,} instructions, {m.boot_s * 1e3:.3f} ms virtual (1 IPC at the modelled HCLK), "
          f"{m.host_s:.2f} s host; SEV x{m.boot_sev}, WFE wake-ups x{m.boot_wfe}")
    tasks = fig["tasks"]
    print(f"  tasks polled {len(tasks['polled'])}/{tasks['expected']}: "
          + ", ".join(f"{k} x{v}" for k, v in sorted(tasks["polls"].items())))
    print(f"  peripherals: {', '.join(sorted(m.touched))}")
    if m.unknown_blocks:
        print(f"  reserved blocks touched: {', '.join(run['unknown_blocks'])}")
    for e in m.events:
        if e["kind"] in ("rcc_pllon", "clock", "iwdg_start", "dma_en", "cpacr", "flash_latency", "rcc_rmvf",
                         "flash_erase", "direct_boot", "vtor", "images"):
            print(f"    {e['t_us'] / 1e3:8.3f} ms  insn {e['insn']:>9,}  {e['text']}")
    if fig.get("nvic_enabled"):
        bound = [i for i in fig["nvic_enabled"] if not i["default_handler"]]
        unbound = [i for i in fig["nvic_enabled"] if i["default_handler"]]
        print("  NVIC enabled: " + ", ".join(f"{i['name']}({i['irq']}) prio {i['priority'] >> 4}" for i in bound))
        if unbound:
            print("  NVIC enabled with DefaultHandler as vector (would spin there if they ever fired): "
                  + ", ".join(i["name"] for i in unbound))
    if m.log:
        print("  firmware log (defmt, decoded from _defmt_write):")
        for e in m.log[:30]:
            print(f"    {e['timestamp']:>10} {e['level']:5} {e['text']}")
    if "frames" in fig:
        fr = fig["frames"]
        print(f"  frames: {fr['result']}")
        if fr["irqs_delivered"]:
            print("    interrupts delivered: " + ", ".join(f"{k} x{v}" for k, v in fr["irqs_delivered"].items()))
        if fr["instructions_per_frame"]:
            print(f"    {fr['instructions']:,} instructions for {m.frames_fed} frames = {fr['instructions_per_frame']:,} "
                  f"per frame (link task, pipeline, bus, interrupts) = {fr['instructions_per_frame'] * args.frame_rate / 1.68e6:.1f} "
                  f"% of 168 MHz at {args.frame_rate:g} frames/s (1 IPC), {fr['host_s']:.2f} s host")
        kinds = collections.Counter(msg.get("kind", "?") for msg in m.bus_msgs)
        if kinds:
            print("    bus messages sent: " + ", ".join(f"{k} x{v}" for k, v in kinds.items()))
        if m.first_fused:
            f = m.first_fused
            print(f"    first Fused: {f['len']} B CSP packet, protocol version {f.get('version')}, seq {f.get('seq')}, "
                  f"link CRC {'ok' if f.get('link_crc_ok') else 'BAD'}")
    big = [f for f in fig["static_frames"] if f["sub_sp"] >= 4096]
    if big:
        print("  largest explicit frames (static scan of `sub sp`):")
        for f in big:
            flag = "  <-- larger than the whole stack region" if f["exceeds_stack"] else ""
            print(f"    {f['sub_sp']:>7} B  {f['function']}{' (reached)' if f['reached'] else ' (not reached)'}{flag}")
    for w in m.warnings[:15]:
        print(f"  warning: {w['text']}  @{img.where(w['pc'])}")
    print()
    skipped = [r["name"] for r in results if r["skipped"]]
    for r in results:
        if r["skipped"]:
            continue
        print(f"  {'PASS' if r['ok'] else 'FAIL'}  {r['name']}: {r['measured']}"
              + (f"   [want {r['expected']}]" if not r["ok"] and r["expected"] else "")
              + (f"  ({r['detail']})" if r["detail"] else ""))
    if skipped:
        print(f"  SKIP  {len(skipped)} checks of the state at idle (the boot did not reach idle): " + "; ".join(skipped))
    print()
    print("RESULT: " + ("PASS" if out["passed"] else "FAIL"))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1, default=str)
    return out["passed"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("elf", help="the firmware ELF (target/thumbv7em-none-eabihf/fw/firmware)")
    ap.add_argument("--json", metavar="PATH", help="write all figures, events and assertions as JSON")
    ap.add_argument("--max-stack-percent", type=float, default=80.0,
                    help="fail if the stack high-water mark exceeds this share of the region (default 80)")
    ap.add_argument("--require-iwdg-before-clock", action="store_true",
                    help="fail unless the IWDG is started (KR=0xCCCC) before the first PLLON write")
    ap.add_argument("--timeout", type=float, default=20.0, help="host-time budget, seconds (default 20)")
    ap.add_argument("--spin-limit", type=int, default=200_000,
                    help="stop as stuck after this many identical reads of one register in a row (default 200k)")
    ap.add_argument("--max-insns", type=int, default=50_000_000, help="instruction budget (default 50M)")
    ap.add_argument("--frames", metavar="FILE",
                    help="after the boot checks, feed this FPGA byte stream (240-byte frames; 'synth' or 'synth:N' "
                         "generates N valid frames, default 200) into USART1's RX DMA ring, delivering interrupts, "
                         "until the first Fused report leaves on USART2 (stretch mode: see the docstring)")
    ap.add_argument("--frame-rate", type=float, default=604.8, help="frames per second of virtual time (604.8)")
    ap.add_argument("--max-frames", type=int, default=400, help="stop feeding after this many frames (400)")
    ap.add_argument("--fused", type=int, default=1, metavar="N", help="with --frames: run until N Fused reports (1)")
    ap.add_argument("--flash-timing", choices=["typ", "max"], default="max",
                    help="flash erase/program durations from DS8626, typical or maximum (default max)")
    ap.add_argument("--flash-bsy-polls", type=int, default=1,
                    help="reads of FLASH_SR that see BSY after each flash operation (default 1)")
    ap.add_argument("-v", "--verbose", action="store_true", help="print events and first peripheral accesses live")
    ap.add_argument("--trace-mmio", action="store_true", help="print every peripheral access (very verbose)")
    args = ap.parse_args(argv)
    if not os.path.isfile(args.elf):
        print(f"boot.py: no such file: {args.elf}", file=sys.stderr)
        return 2
    try:
        img = Image(args.elf, args.verbose)
    except ToolError as e:
        print(e, file=sys.stderr)
        return 2
    if not img.task_polls:
        print("boot.py: no TaskStorage<F>::poll function in the ELF (not an embassy firmware?)", file=sys.stderr)
        return 2
    if not img.wfe:
        print("boot.py: no WFE instruction in the ELF (not the thread executor?)", file=sys.stderr)
        return 2
    stream = None
    if args.frames:
        if args.frames.startswith("synth"):
            stream = synth_frames(int(args.frames.split(":")[1]) if ":" in args.frames else 200)
        else:
            with open(args.frames, "rb") as f:
                stream = f.read()
    try:
        m = Machine(img, args)
    except ToolError as e:
        print(e, file=sys.stderr)
        return 2
    m.run(args.timeout, args.max_insns)
    results, fig = check(m, args)
    if stream is not None:
        if m.stop_kind == "idle":
            m.frames_phase(stream, args.frame_rate, args.max_frames, args.fused)
        check_frames(m, args, results, fig)
    return 0 if report(m, img, results, fig, args) else 1


if __name__ == "__main__":
    sys.exit(main())
