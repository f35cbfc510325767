#!/usr/bin/env python3
"""Worst-case stack usage of the firmware ELF (STM32F405, Cortex-M4F, thumbv7em-none-eabihf).

Usage:
    python3 tools/fw-check/boot.py target/thumbv7em-none-eabihf/fw/firmware --json boot.json   # priorities
    python3 tools/fw-check/stack.py target/thumbv7em-none-eabihf/fw/firmware \
        [--json out.json] [--markdown] [--max-percent 75] [--max-frame 8192] [--min-region BYTES]
        [--allow-recursion SUBSTRING ...] [--boot-json boot.json]

Exit status: 0 when every check passes, 1 when a check fails (the reasons are printed last), 2 on a usage or tool
error (no ELF, no llvm-objdump, no symbol table). Needs Python 3.11, pyelftools and llvm-objdump (Debian: llvm).

This firmware needs ``--allow-recursion core::fmt --allow-recursion core::panicking``: ``core::fmt`` recurses
through ``dyn Display``/``Debug``/``Write`` (nesting of the formatted values), and a panic can recur while the
panic handler formats its message (defmt-rtt panics on a re-entrant acquire, which the panic handler's own
``defmt::error!`` would then hit again: unbounded in principle, ending in a HardFault through flip-link).

Method
------
1. Disassembly: ``llvm-objdump -d --no-show-raw-insn`` of the ELF; names are demangled here (legacy Rust
   ``_ZN…17h<hash>E``; v0 ``_R…`` through ``llvm-cxxfilt`` when present). Functions are the ``STT_FUNC`` symbols of
   the executable sections; aliases (one address, several names: ``Reset``/``__stext``, ``DefaultHandler``/
   ``DefaultHandler_``/every unused IRQ name) are one function. A function's extent is its symbol size, or up to the
   next symbol when the size is 0.
2. Frame per function: a data-flow pass over the function's control-flow graph (fall-through, branches, IT blocks,
   ``tbb``/``tbh`` tables read from the bytes objdump prints after them) tracks the SP offset below the entry SP:
   ``push``/``stmdb sp!`` (+4 B per register, lr included), ``vpush``/``vstmdb sp!`` (+8 B per d register, +4 per s
   register), ``sub sp, #N``/``sub(.w) sp, sp, #N``/``subw``, ``str rX, [sp, #-N]!`` and their inverses. An SP
   restored from a register is followed when that register holds a known SP-relative value (``mov r7, sp`` /
   ``add r7, sp, #k`` then ``mov sp, r7`` / ``sub sp, r7, #k``; ``bfc`` realignment adds its worst padding) or a
   known constant (``movw``/``movt``/``mov #imm`` then ``sub sp, rN``). At a join the larger offset is kept; a
   predicated (IT) SP change keeps the larger of "taken" and "not taken". The frame is the largest offset reached
   anywhere in the function. Code the flow does not reach (after a computed jump, or padding) is analysed too,
   entered at the largest offset seen so far. Any other write of SP (``sub sp, rN`` with an unknown rN,
   ``mov sp, rN``, ``msr msp``/``msr psp``, an SP that keeps going down round a loop) makes the function UNBOUNDED,
   with one exception, the *entry stack switch*: a function whose first instructions, in a straight line, only
   read registers (``mrs``, ``mov``), build constants (``movw``/``movt``/``mov #imm``) or load literals
   (``ldr rN, [pc, #k]``, the word read from the pool) and then ``msr msp, rN`` with rN a known constant — no
   store, push, SP write, call or branch before it. Its offsets after the switch count from the new SP. This is
   accepted only for the HardFault or NMI vector's own function, never called, not also the handler of another
   vector, and only when the new SP is the top of a data symbol in writable memory (``start < SP <= start +
   size``; the usable size is SP - start) outside the main stack region; otherwise it stays UNBOUNDED.
3. Call graph, with the SP offset at each call site (what the caller keeps live while the callee runs; a tail call
   after the epilogue runs at offset 0, so it does not add the caller's frame): ``bl``/``blx <addr>``; tail calls:
   ``b``/``b.w``/a conditional branch/``cbz`` whose target is outside the function or another function's start.
   Indirect: ``blx rN``; indirect tail calls ``bx rN`` (rN != lr), ``mov pc, rN``, ``ldr pc, […]`` (not a
   return). ``tbb``/``tbh`` are jump tables inside the function, not calls.
4. Indirect calls, in two classes; each site becomes an edge to every possible target, so a recursion through a
   function pointer is a cycle of real functions and the reported path names the target:
   a. the Embassy executor (a function named ``embassy_executor::…{SyncExecutor::poll, Executor::poll,
      thread::Executor::run, InterruptExecutor::on_interrupt}``; ``SyncExecutor::poll`` is inlined into
      ``thread::Executor::run`` in this build) polls tasks through ``TaskHeader::poll_fn``: its indirect calls go to
      the task poll functions (``embassy_executor::raw::TaskStorage<F>::poll``) and ``raw::poll_exited``;
   b. every other indirect call goes to every *address-taken* function: one whose start|1 (Thumb bit) occurs as an
      aligned 32-bit word in the ``.text`` literal pools, ``.rodata``, ``.data`` or any other loaded section, or is
      built in a register by ``movw``/``movt`` (or ``adr``). The vector table is not scanned: its handlers are
      roots, address-taken only if referenced elsewhere too. The task polls are left out (their address is only
      stored into ``TaskHeader::poll_fn``, which only the executor calls). The bound is the deepest of them, so a
      call through a waker vtable is charged like the deepest ``fmt`` impl.
   Tasks are named from DWARF (``poll<firmware::__fpga_link_task::…>`` -> ``fpga_link``): legacy mangling drops
   the generic argument of ``TaskStorage<F>``.
5. Recursion: strongly connected components of the graph the roots reach. A component is an error unless every
   cycle in it passes through a function whose name contains a ``--allow-recursion`` substring (the component
   minus those functions is acyclic). Its bound is then the *acyclic* bound, one pass through the cycles: from
   each entry into the component a depth-first search (deepest calls first) drops the calls that close a cycle
   (back edges), and the deepest remaining path counts.
6. Roots: ``Reset`` (thread mode: init, ``main``, the executor and, through it, every task); each task poll
   function; each distinct handler in ``.vector_table`` (word 0 = initial SP, 1..15 exceptions, 16.. IRQs;
   ``DefaultHandler`` once), ``HardFault`` included (cortex-m-rt 0.7: ``HardFault`` trampoline -> ``_HardFault`` ->
   the user's handler; this firmware: its own assembly ``HardFault`` that moves MSP to ``FAULT_STACK`` and
   tail-calls ``fdir_hard_fault``, see 2.).
7. Total for the main stack (MSP; thread mode uses it too) = worst thread path + Σ over the distinct preemption
   levels, highest priority first, of (deepest handler of the level + exception entry) + HardFault + (NMI + entry).
   Exception entry = 26 words (FPU on: lazy stacking reserves S0-S15/FPSCR) = 104 B + 4 B alignment pad = 108 B.
   Levels: a handler preempts only a lower level, so one frame nests per distinct level; handlers of one level do
   not nest among themselves. Priorities come from ``--boot-json`` (``figures.nvic_enabled`` of ``boot.py
   --json``: the raw 8-bit NVIC_IPR value of every IRQ enabled when the emulated boot ended). AIRCR.PRIGROUP is
   left at 0 and the F4 implements 4 priority bits, so the preemption level = priority >> 4. A vector with a
   handler but no priority in the JSON (an IRQ not enabled then, MemManage/BusFault/UsageFault/SVCall/
   DebugMonitor/PendSV: ``DefaultHandler`` here) is taken at priority 0, the reset value: the highest configurable
   level. SysTick's priority is a system handler's (SHPR3), which boot.py does not report today
   (``figures.system_priorities``, {name or number: raw priority}, is read if present): without it SysTick is a
   level of its own above every IRQ. A function bound to vectors of several levels counts in each. Without
   ``--boot-json`` the priorities are not known: every handler function is a level of its own (a safe upper bound:
   any handler may nest on any other) and the report says so. HardFault (fixed priority -1) can preempt any
   handler: its worst path + entry, or, when it moves MSP to a stack of its own (2.), only its hardware frame
   (entry) — kept in the MSP total although after a stack overflow the push itself may fail, which is why the
   handler has a stack of its own. NMI (-2) preempts everything, HardFault included; it is counted whatever its
   handler (``DefaultHandler`` too). A boot JSON whose ``run.sha256`` is of another ELF is an error.
8. Region = ``_stack_start`` - ``_stack_end`` (flip-link puts the stack at the bottom of RAM). A separate stack
   (2.) is checked on its own: its handler's worst path + (NMI + entry: an NMI during the HardFault handler
   stacks on the same stack) ≤ ``--max-percent`` of its size, reported on its own line and in the JSON
   (``total.separate_stacks``).

Checks (exit 1): total > ``--max-percent`` of the region; a separate stack's worst case > ``--max-percent`` of it;
a frame > ``--max-frame`` anywhere in the ELF; a cycle not allowed; an unbounded frame (an ``msr msp`` that is not
an accepted entry switch included), or a call to an address in no function, reachable from a root; a
``--boot-json`` of another ELF.

Limits: what is over-approximated, what could be missed
-------------------------------------------------------
* Over-approximated: a frame is the deepest SP offset anywhere in the function, on any path; an indirect call is
  charged the deepest address-taken function (nested ones too, each function once per path) even if its real
  targets are shallow; a path through a call that never returns is still followed; the handler and HardFault
  levels are added as if they struck at the thread's deepest point.
* Could be missed: calls through an address computed at run time other than from a literal word, ``movw``/
  ``movt`` or ``adr`` (e.g. base + offset arithmetic), or to code with no function symbol (it is reported as a
  call to an address in no function); SP changes inside inline asm in forms not listed in 2.; recursion deeper
  than one pass where allowed (and, in odd graphs, a simple path that the search order drops); code outside
  ``.text`` (RAM functions); instructions between function symbols (counted in a warning); priorities changed
  after the end of the emulated boot (the boot JSON is a snapshot at idle: an IRQ enabled later is taken at
  priority 0, but a priority lowered later is not seen; BASEPRI is not modelled — it can only reduce nesting);
  a PRIGROUP other than 0 (fewer preemption levels: only fewer frames nest, so the figure stays an upper bound).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field

EXC_FRAME = 26 * 4  # R0-R3, R12, LR, PC, xPSR + S0-S15, FPSCR, reserved (FPU on, lazy stacking reserves it)
EXC_ALIGN = 4  # STKALIGN: up to 4 B of padding to keep the frame 8-aligned
EXC_ENTRY = EXC_FRAME + EXC_ALIGN
# AIRCR.PRIGROUP = 0 (reset value; the firmware leaves it) and 4 implemented priority bits on the STM32F4: the
# preemption level is the 8-bit NVIC_IPR/SHPR value >> 4 (the subpriority field, bits 3..0, is not implemented).
PREEMPT_SHIFT = 4

CONDS = {"eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt", "le", "al"}
CORE_REGS = {f"r{i}" for i in range(13)} | {"sb", "sl", "fp", "ip"}
REG_ALIAS = {"sb": "r9", "sl": "r10", "fp": "r11", "ip": "r12"}
# Mnemonics (condition and width stripped) whose first operand is not a register they write.
NO_DEST = {
    "str", "strb", "strh", "strd", "stm", "stmia", "stmdb", "stmea", "stmfd", "push", "vpush", "vstr", "vstm",
    "vstmia", "vstmdb", "cmp", "cmn", "tst", "teq", "b", "bl", "blx", "bx", "cbz", "cbnz", "msr", "dmb", "dsb",
    "isb", "nop", "wfe", "wfi", "sev", "bkpt", "udf", "svc", "cpsid", "cpsie", "pld", "pli", "tbb", "tbh", "vcmp",
    "vcmpe", "vmsr", "yield", "clrex", "stc", "mcr", "mcrr",
}
LOOP_LIMIT = 1 << 20  # an SP offset beyond 1 MiB can only come from SP decreasing round a loop

EXECUTOR_RE = re.compile(
    r"embassy_executor::.*(SyncExecutor::poll|Executor::poll|thread::Executor::run|InterruptExecutor::on_interrupt)"
)
TASK_POLL_RE = re.compile(r"TaskStorage<.*>::poll")
POLL_EXITED_RE = re.compile(r"embassy_executor::raw::poll_exited")

EXC_NAMES = {
    1: "Reset", 2: "NMI", 3: "HardFault", 4: "MemoryManagement", 5: "BusFault", 6: "UsageFault",
    11: "SVCall", 12: "DebugMonitor", 14: "PendSV", 15: "SysTick",
}


# --------------------------------------------------------------------------------------------------------------------
# Names


def _legacy_rust_demangle(name: str) -> str | None:
    """Demangle a legacy Rust symbol (``_ZN…17h<hash>E``); the hash is dropped. None if it is not one."""
    s = name
    if s.startswith("__ZN"):
        s = s[1:]
    if not s.startswith("_ZN"):
        return None
    i, parts = 3, []
    while i < len(s) and s[i] != "E":
        j = i
        while j < len(s) and s[j].isdigit():
            j += 1
        if j == i:
            return None
        n = int(s[i:j])
        parts.append(s[j : j + n])
        i = j + n
    if i >= len(s):
        return None
    if parts and re.fullmatch(r"h[0-9a-f]{16}", parts[-1]):
        parts.pop()
    esc = {"SP": "@", "BP": "*", "RF": "&", "LT": "<", "GT": ">", "LP": "(", "RP": ")", "C": ","}

    def unescape(p: str) -> str:
        if p.startswith("_$"):
            p = p[1:]
        out, k = [], 0
        while k < len(p):
            if p[k] == "$":
                e = p.find("$", k + 1)
                code = p[k + 1 : e] if e > 0 else ""
                if code in esc:
                    out.append(esc[code])
                elif code.startswith("u") and re.fullmatch(r"u[0-9a-f]+", code):
                    out.append(chr(int(code[1:], 16)))
                else:
                    out.append(p[k:])
                    break
                k = e + 1
            elif p.startswith("..", k):
                out.append("::")
                k += 2
            else:
                out.append(p[k])
                k += 1
        return "".join(out)

    return "::".join(unescape(p) for p in parts)


def demangle_all(names: list[str]) -> dict[str, str]:
    """Demangle every name: legacy Rust here, anything else (v0 ``_R``, C++) through llvm-cxxfilt if present."""
    out, rest = {}, []
    for n in names:
        d = _legacy_rust_demangle(n)
        if d is not None:
            out[n] = d
        elif n.startswith(("_R", "_Z", "__Z")):
            rest.append(n)
        else:
            out[n] = n
    tool = shutil.which("llvm-cxxfilt") or shutil.which("rustfilt")
    if rest and tool:
        try:
            res = subprocess.run([tool], input="\n".join(rest) + "\n", capture_output=True, text=True, check=True)
            for n, d in zip(rest, res.stdout.splitlines()):
                out[n] = re.sub(r"::h[0-9a-f]{16}$", "", d.strip()) or n
        except (OSError, subprocess.CalledProcessError):
            pass
    for n in rest:
        out.setdefault(n, n)
    return out


def short_name(name: str, width: int = 60) -> str:
    """A readable abbreviation of a demangled name: generic arguments elided, cut to ``width``."""
    s = name
    # Elide nested generic arguments, innermost first, but keep a leading <X as Y> qualification.
    for _ in range(8):
        t = re.sub(r"(?<=[A-Za-z0-9_])<[^<>]*>", "<…>", s)
        if t == s:
            break
        s = t
    if len(s) > width:
        s = "…" + s[-(width - 1) :]
    return s


def task_label(dwarf_name: str | None, demangled: str) -> str:
    """``poll<firmware::__fpga_link_task::__fpga_link_task_inner_function::{async_fn_env#0}>`` -> ``fpga_link``."""
    src = None
    if dwarf_name and "<" in dwarf_name:
        src = dwarf_name[dwarf_name.index("<") + 1 : dwarf_name.rindex(">")]
    else:
        m = re.search(r"TaskStorage<(.+)>::poll", demangled)
        if m and m.group(1) != "F":
            src = m.group(1)
    if not src:
        return demangled
    m = re.search(r"(?:^|::)_*([A-Za-z0-9_]+?)_task(?:::|$)", src)
    if m:
        return m.group(1)
    parts = [p for p in src.split("::") if not p.startswith("{")]
    return "::".join(parts[-2:]) if parts else src


# --------------------------------------------------------------------------------------------------------------------
# Disassembly


@dataclass
class Insn:
    addr: int
    mnem: str  # as printed, lower case
    ops: str  # operands, comment and <label> removed
    target: int | None  # branch/call target when the operand is an address
    text: str  # the whole line, for messages


LINE_RE = re.compile(r"^\s*([0-9a-f]+):\s*\t(.*)$")
LABEL_RE = re.compile(r"^([0-9a-f]+) <(.*)>:\s*$")
HEXBYTES_RE = re.compile(r"^(?:[0-9a-f]{2} ?)+$")


def parse_objdump(text: str):
    """Parse ``llvm-objdump -d --no-show-raw-insn`` output.

    Returns (insns sorted by address, labels {addr: [names]}, data {addr: bytes}) — data are the literal-pool and
    jump-table bytes that objdump prints as ``.word``/``.short``/``.byte`` with their raw bytes."""
    insns, labels, data = [], {}, {}
    for line in text.splitlines():
        m = LABEL_RE.match(line)
        if m:
            labels.setdefault(int(m.group(1), 16), []).append(m.group(2))
            continue
        m = LINE_RE.match(line)
        if not m:
            continue
        addr = int(m.group(1), 16)
        fields = [f.strip() for f in m.group(2).split("\t")]
        fields = [f for f in fields if f != ""]
        if not fields:
            continue
        if HEXBYTES_RE.match(fields[0]) and len(fields) > 1 and fields[1].startswith("."):
            data[addr] = bytes(int(b, 16) for b in fields[0].split())
            continue
        if fields[0].startswith("."):
            continue
        mnem = fields[0].lower()
        rest = " ".join(fields[1:])
        ops = rest.split("@", 1)[0]
        target = None
        tm = re.match(r"\s*(?:(?:r\d+|sb|sl|fp|ip),\s*)?0x([0-9a-f]+)\b", ops)
        if tm:
            target = int(tm.group(1), 16)
        ops = re.sub(r"\s*<.*$", "", ops).strip()
        insns.append(Insn(addr, mnem, ops, target, line.strip()))
    insns.sort(key=lambda i: i.addr)
    return insns, labels, data


def is_padding(ins: Insn) -> bool:
    """Fill between functions: 0x0000 (``movs r0, r0``), ``nop``, ``udf``, lld's 0xd4d4 (``bmi`` back 84 B)."""
    return (ins.mnem in ("nop", "nop.w", "udf", "udf.w") or (ins.mnem == "movs" and ins.ops == "r0, r0")
            or (ins.mnem == "bmi" and ins.target == ins.addr - 84))


def split_ops(ops: str) -> list[str]:
    out, depth, cur = [], 0, []
    for ch in ops:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    if cur and "".join(cur).strip():
        out.append("".join(cur).strip())
    return out


def reg_list(ops: str) -> list[str]:
    m = re.search(r"\{([^}]*)\}", ops)
    if not m:
        return []
    regs = []
    for item in m.group(1).split(","):
        item = item.strip()
        rm = re.fullmatch(r"([a-z]+)(\d+)\s*-\s*([a-z]+)(\d+)", item)
        if rm and rm.group(1) == rm.group(3):
            regs += [f"{rm.group(1)}{k}" for k in range(int(rm.group(2)), int(rm.group(4)) + 1)]
        elif item:
            regs.append(REG_ALIAS.get(item, item))
    return regs


def imm(op: str) -> int | None:
    m = re.fullmatch(r"#(-?(?:0x[0-9a-f]+|\d+))", op.strip())
    return int(m.group(1), 0) if m else None


def norm_reg(op: str) -> str:
    op = op.strip().rstrip("!")
    return REG_ALIAS.get(op, op)


# --------------------------------------------------------------------------------------------------------------------
# Per-function analysis


@dataclass
class Site:
    addr: int
    kind: str  # "call", "tail", "indirect", "indirect-tail"
    offset: int  # SP offset (bytes below entry SP) live at the call
    target: int | None  # address for direct calls
    text: str


@dataclass
class FuncInfo:
    start: int
    end: int
    name: str  # demangled, canonical alias
    raw: str  # symbol as in the ELF
    aliases: list[str] = field(default_factory=list)
    frame: int = 0
    unbounded: list[str] = field(default_factory=list)  # reasons
    sites: list[Site] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    insn_count: int = 0
    # ``msr msp`` at entry to a constant, before any store (see ``_entry_stack_switch``): {"address", "value", "text"}
    stack_switch: dict | None = None


class _State:
    __slots__ = ("off", "regs")

    def __init__(self, off: int, regs: dict):
        self.off = off
        self.regs = regs  # reg -> ("sp", off_of_value) | ("c", constant)

    def merge(self, other: "_State") -> bool:
        """Join another state into this one; True when this one changed."""
        changed = False
        if other.off > self.off:
            self.off = other.off
            changed = True
        for r in list(self.regs):
            if other.regs.get(r) != self.regs[r]:
                del self.regs[r]
                changed = True
        return changed


def _base(mnem: str, predicated: bool) -> str:
    b = mnem.split(".")[0]
    if predicated and len(b) > 2 and b[-2:] in CONDS:
        b = b[:-2]
    return b


def _dests(base: str, ops: list[str], raw_ops: str) -> set[str]:
    """Core registers an instruction writes (enough for tracking r7/SP copies and constants)."""
    d: set[str] = set()
    if base in ("pop", "ldm", "ldmia", "ldmfd", "ldmdb", "ldmea"):
        d |= {r for r in reg_list(raw_ops) if r in CORE_REGS or r.startswith("r")}
    if base.startswith(("ldm", "stm", "ldr", "str", "vldm", "vstm")):
        wb = re.search(r"\[(\w+)[^\]]*\]!|\[(\w+)\],|^(\w+)!", raw_ops)
        if wb:
            d.add(norm_reg(wb.group(1) or wb.group(2) or wb.group(3)))
    if base in ("bl", "blx"):
        d |= {"r0", "r1", "r2", "r3", "r12", "lr"}
    if base.startswith("strex"):
        d.add(norm_reg(ops[0]))
        return d
    if base in NO_DEST or base.startswith(("str", "stm", "vst", "b")) and base not in ("bfc", "bfi", "bic", "bics"):
        return d
    nd = 2 if base in ("ldrd", "ldrexd", "umull", "smull", "umlal", "smlal", "vmov") else 1
    for op in ops[:nd]:
        r = norm_reg(op)
        if r in CORE_REGS or re.fullmatch(r"r\d+", r) or r == "lr":
            d.add(r)
    return d


def _literal_word(data: dict[int, bytes], addr: int) -> int | None:
    """The 32-bit little-endian word at ``addr`` from the literal bytes objdump printed, or None."""
    raw = bytearray()
    a = addr
    while len(raw) < 4:
        chunk = data.get(a)
        if chunk is None:
            # objdump may print a pool as one line spanning ``addr``: find the line that contains it.
            start = next((b for b in data if b < a < b + len(data[b])), None) if not raw else None
            if start is None:
                return None
            chunk = data[start][a - start :]
        raw += chunk
        a += len(chunk)
    return int.from_bytes(raw[:4], "little")


# Instructions allowed before the ``msr msp`` of an entry stack switch: they neither store nor move SP nor branch.
_SWITCH_PREFIX_OK = {"mrs", "mov", "movs", "movw", "movt", "mvn", "mvns", "ldr", "cpsid", "nop", "isb", "dsb", "dmb"}


def _entry_stack_switch(insns: list[Insn], data: dict[int, bytes]) -> dict | None:
    """A stack switch at the function's entry: straight-line instructions from the first one that only read
    registers, build constants (``movw``/``movt``/``mov #imm``) or load a literal (``ldr rN, [pc, #k]``), then
    ``msr msp, rN`` with rN a known constant. No store, push, SP write, call or branch may come before it (they
    would run on the old stack). Returns {"address", "value", "text"} or None."""
    regs: dict[str, int] = {}
    for ins in insns[:16]:
        base = ins.mnem.split(".")[0]
        ops = split_ops(ins.ops)
        if base == "msr" and len(ops) == 2 and ops[0] == "msp":
            v = regs.get(norm_reg(ops[1]))
            return None if v is None else {"address": ins.addr, "value": v, "text": ins.text}
        if base not in _SWITCH_PREFIX_OK or not ops and base not in ("nop", "isb", "dsb", "dmb", "cpsid"):
            return None
        if base in ("nop", "isb", "dsb", "dmb", "cpsid"):
            continue
        d = norm_reg(ops[0])
        if d in ("sp", "pc", "lr") or not (d in CORE_REGS or re.fullmatch(r"r\d+", d)):
            return None
        val = None
        if base in ("mov", "movs", "movw") and len(ops) == 2:
            val = imm(ops[1])
            if val is None:
                val = regs.get(norm_reg(ops[1]))
        elif base in ("mvn", "mvns") and len(ops) == 2 and imm(ops[1]) is not None:
            val = ~imm(ops[1])
        elif base == "movt" and len(ops) == 2 and imm(ops[1]) is not None and d in regs:
            val = (regs[d] & 0xFFFF) | (imm(ops[1]) << 16)
        elif base == "ldr":
            m = re.fullmatch(r"\[pc, #(-?\d+)\]", ops[1]) if len(ops) == 2 else None
            if m is None:
                if len(ops) == 2 and re.fullmatch(r"\[(r\d+|sb|sl|fp|ip|sp)(, #-?\d+)?\]", ops[1]):
                    regs.pop(d, None)  # a load: no store, no SP change; the value is unknown
                    continue
                return None
            val = _literal_word(data, ((ins.addr + 4) & ~3) + int(m.group(1)))
        if val is None:
            regs.pop(d, None)
        else:
            regs[d] = val & 0xFFFFFFFF
    return None


def analyse_function(f: FuncInfo, insns: list[Insn], data: dict[int, bytes], is_func_start) -> None:
    """Fill ``f.frame``, ``f.sites`` and ``f.unbounded`` from the function's instructions (address order)."""
    f.insn_count = len(insns)
    if not insns:
        return
    f.stack_switch = _entry_stack_switch(insns, data)
    switch_addr = f.stack_switch["address"] if f.stack_switch else None
    idx = {ins.addr: k for k, ins in enumerate(insns)}
    n = len(insns)

    # Instructions predicated by an IT block (the block's condition, any instruction).
    pred = [False] * n
    k = 0
    while k < n:
        b = insns[k].mnem
        if re.fullmatch(r"it[te]{0,3}", b):
            for j in range(1, len(b)):
                if k + j < n:
                    pred[k + j] = True
        k += 1

    def inside(a: int) -> bool:
        return f.start <= a < f.end and a in idx and not (a != f.start and is_func_start(a))

    def table_targets(k: int, half: bool) -> list[int]:
        """Targets of a tbb/tbh at index k: the table runs from the next halfword to the next instruction."""
        ins = insns[k]
        base = ins.addr + 4
        end = insns[k + 1].addr if k + 1 < n else f.end
        raw = bytearray()
        a = base
        while a < end:
            chunk = data.get(a)
            if chunk is None:
                break
            raw += chunk
            a += len(chunk)
        step = 2 if half else 1
        out = []
        for p in range(0, len(raw) - step + 1, step):
            v = int.from_bytes(raw[p : p + step], "little")
            t = base + 2 * v
            if t in idx:
                out.append(t)
        return out

    states: list[_State | None] = [None] * n
    max_off = 0
    visits = [0] * n
    sites: dict[tuple[int, str], Site] = {}
    unbounded: dict[int, str] = {}
    notes: list[str] = []
    bad_returns: set[int] = set()

    def add_site(ins: Insn, kind: str, off: int, target: int | None):
        key = (ins.addr, kind)
        s = sites.get(key)
        if s is None:
            sites[key] = Site(ins.addr, kind, off, target, ins.text)
        elif off > s.offset:
            s.offset = off

    def step(k: int, st: _State) -> list[tuple[int, _State]]:
        """Effect of instruction k on a copy of ``st``; returns its successors with their states."""
        nonlocal max_off
        ins = insns[k]
        p = pred[k]
        base = _base(ins.mnem, p)
        ops = split_ops(ins.ops)
        before = st.off
        regs = dict(st.regs)
        off = before
        fall = True
        succ: list[int] = []
        sp_unknown = None

        def dyn(why: str):
            nonlocal sp_unknown
            sp_unknown = why

        dst0 = norm_reg(ops[0]) if ops else ""
        # --- SP updates -------------------------------------------------------------------------------------------
        if base in ("push", "stmdb", "stmfd") and (base == "push" or dst0 == "sp" and ops[0].endswith("!")):
            off += 4 * len(reg_list(ins.ops))
        elif base in ("pop", "ldm", "ldmia", "ldmfd") and (base == "pop" or dst0 == "sp" and ops[0].endswith("!")):
            off -= 4 * len(reg_list(ins.ops))
        elif base in ("vpush", "vstmdb") and (base == "vpush" or dst0 == "sp" and ops[0].endswith("!")):
            off += sum(8 if r.startswith("d") else 4 for r in reg_list(ins.ops))
        elif base in ("vpop", "vldmia", "vldm") and (base == "vpop" or dst0 == "sp" and ops[0].endswith("!")):
            off -= sum(8 if r.startswith("d") else 4 for r in reg_list(ins.ops))
        elif base in ("stm", "stmia", "stmea", "ldmdb", "ldmea") and dst0 == "sp" and ops[0].endswith("!"):
            n_regs = 4 * len(reg_list(ins.ops))
            off += -n_regs if base.startswith("stm") else n_regs
        elif re.search(r"\[sp, #(-?\d+)\]!", ins.ops):
            off -= int(re.search(r"\[sp, #(-?\d+)\]!", ins.ops).group(1))
        elif re.search(r"\[sp\], #(-?\d+)", ins.ops):
            off -= int(re.search(r"\[sp\], #(-?\d+)", ins.ops).group(1))
        elif dst0 == "sp" and base in ("sub", "subw", "subs", "add", "addw", "adds", "mov", "movs"):
            sign = 1 if base.startswith("sub") else -1
            src = ops[1:] if len(ops) >= 2 else []
            if base.startswith("mov"):
                r = norm_reg(src[0]) if src else ""
                v = regs.get(r)
                if v and v[0] == "sp":
                    off = v[1]
                else:
                    dyn(f"SP set from {r or '?'} (value unknown)")
            elif len(src) == 1:  # sub sp, #N / sub sp, rN
                v = imm(src[0])
                if v is None:
                    c = regs.get(norm_reg(src[0]))
                    if c and c[0] == "c":
                        v = c[1]
                if v is None:
                    dyn(f"SP adjusted by {src[0]} (value unknown)")
                else:
                    off += sign * v
            elif len(src) >= 2:
                r1 = norm_reg(src[0])
                v = imm(src[1])
                if v is None and len(src) == 2:
                    c = regs.get(norm_reg(src[1]))
                    if c and c[0] == "c":
                        v = c[1]
                if v is None or len(src) > 2:
                    dyn(f"SP adjusted by {', '.join(src[1:])} (value unknown)")
                elif r1 == "sp":
                    off += sign * v
                else:
                    rv = regs.get(r1)
                    if rv and rv[0] == "sp":
                        off = rv[1] + sign * v
                    else:
                        dyn(f"SP set from {r1} (value unknown)")
        elif dst0 == "sp" and base not in NO_DEST and not base.startswith(("str", "stm", "vst", "ldm", "vldm")):
            dyn("SP written by an instruction the analysis does not model")
        elif base == "msr" and ops and ops[0] in ("msp", "psp"):
            if ins.addr == switch_addr and not p and before == 0:
                pass  # the entry switch: what follows runs on the new stack, its offsets counted from its top
            else:
                dyn(f"stack pointer switched ({ops[0]})")

        if sp_unknown is not None:
            unbounded.setdefault(ins.addr, f"{sp_unknown}: {ins.text}")
            # Keep going with the offset unchanged, so that the calls after it are still found.
        if p:
            off = max(off, before)  # executed or not: keep the larger

        # --- register tracking (r7 and other SP copies, constants) --------------------------------------------------
        new_vals = {}
        if len(ops) >= 2 and base in ("mov", "movs", "add", "addw", "adds", "sub", "subw", "subs", "movw", "movt",
                                      "mvn", "mvns", "bfc", "bic", "bics"):
            d = norm_reg(ops[0])
            s1 = norm_reg(ops[1])
            if base in ("mov", "movs") and s1 == "sp":
                new_vals[d] = ("sp", before)
            elif base in ("mov", "movs", "movw") and imm(ops[1]) is not None:
                new_vals[d] = ("c", imm(ops[1]) & 0xFFFFFFFF)
            elif base in ("mvn", "mvns") and imm(ops[1]) is not None:
                new_vals[d] = ("c", ~imm(ops[1]) & 0xFFFFFFFF)
            elif base == "movt" and imm(ops[1]) is not None:
                lo = regs.get(d)
                if lo and lo[0] == "c":
                    new_vals[d] = ("c", (lo[1] & 0xFFFF) | (imm(ops[1]) << 16))
            elif base in ("add", "addw", "adds", "sub", "subw", "subs") and len(ops) == 3 and s1 == "sp":
                v = imm(ops[2])
                if v is not None:
                    new_vals[d] = ("sp", before - v if base.startswith("add") else before + v)
            elif base == "bfc" and len(ops) == 3 and regs.get(d, ("",))[0] == "sp":
                lsb, width = imm(ops[1]), imm(ops[2])
                if lsb == 0 and width is not None:
                    new_vals[d] = ("sp", regs[d][1] + (1 << width) - 4)  # realigned down: at most 2^w - 4 more
            elif base in ("bic", "bics") and len(ops) == 3 and norm_reg(ops[1]) == d and regs.get(d, ("",))[0] == "sp":
                v = imm(ops[2])
                if v is not None and (v & (v + 1)) == 0:
                    new_vals[d] = ("sp", regs[d][1] + v + 1 - 4)
        for r in _dests(base, ops, ins.ops):
            regs.pop(r, None)
        if not p:
            regs.update(new_vals)

        if off > max_off:
            max_off = off

        # --- control flow -----------------------------------------------------------------------------------------
        if base == "b" or (base[:1] == "b" and base[1:] in CONDS and base not in ("bl",)) or base in ("cbz", "cbnz"):
            conditional = p or base in ("cbz", "cbnz") or base != "b"
            t = ins.target
            if t is not None and inside(t):
                succ.append(t)
            elif t is not None:
                add_site(ins, "tail", before, t)
            else:
                add_site(ins, "indirect-tail", before, None)
            fall = conditional
        elif base in ("bl", "blx"):
            if ins.target is not None:
                add_site(ins, "call", before, ins.target)
            else:
                add_site(ins, "indirect", before, None)
        elif base == "bx":
            if norm_reg(ops[0]) != "lr":
                add_site(ins, "indirect-tail", before, None)
            elif not p and off != 0:
                bad_returns.add(ins.addr)
            fall = p
        elif base in ("pop", "ldm", "ldmia", "ldmfd") and "pc" in reg_list(ins.ops):
            if not p and off != 0:
                bad_returns.add(ins.addr)
            fall = p
        elif base.startswith("ldr") and ops and ops[0] == "pc":
            if not re.search(r"\[sp\], #", ins.ops):
                add_site(ins, "indirect-tail", before, None)
            fall = p
        elif base in ("mov", "add") and ops and ops[0] == "pc":
            add_site(ins, "indirect-tail", before, None)  # computed jump: also inside (see unreached code)
            fall = p
        elif base in ("tbb", "tbh"):
            succ += table_targets(k, base == "tbh")
            fall = False
        elif base == "udf" or (base == "b" and ins.target == ins.addr):
            fall = False
        if fall and k + 1 < n and insns[k + 1].addr < f.end:
            succ.append(insns[k + 1].addr)
        nst = _State(off, regs)
        return [(a, nst) for a in succ]

    def run(seeds: list[tuple[int, _State]]):
        work = list(seeds)
        while work:
            k, st = work.pop()
            cur = states[k]
            if cur is None:
                states[k] = _State(st.off, dict(st.regs))
            elif not cur.merge(st):
                continue
            visits[k] += 1
            if states[k].off > LOOP_LIMIT or visits[k] > 10000:
                unbounded.setdefault(insns[k].addr, f"SP keeps decreasing round a loop: {insns[k].text}")
                continue
            for a, nst in step(k, states[k]):
                work.append((idx[a], nst))

    run([(0, _State(0, {}))])
    # Code the flow did not reach (a computed jump's targets, tables of b.w, padding): enter it at the deepest
    # offset seen so far, which bounds any state a jump from reached code could carry.
    for k in range(n):
        if states[k] is None:
            if is_padding(insns[k]):
                continue
            run([(k, _State(max_off, {}))])
            notes.append(f"unreached code from {insns[k].addr:#x} analysed at the function's deepest offset")

    f.frame = max(0, max_off)
    f.sites = sorted(sites.values(), key=lambda s: (s.addr, s.kind))
    f.unbounded = list(unbounded.values())
    if bad_returns:
        notes.append("returns with a nonzero SP offset at " + ", ".join(f"{a:#x}" for a in sorted(bad_returns))
                     + " (a join kept the larger offset: over-approximated)")
    f.notes = notes


# --------------------------------------------------------------------------------------------------------------------
# Program


@dataclass
class Program:
    funcs: dict[int, FuncInfo]  # by start address (Thumb bit clear)
    address_taken: set[int]  # function starts whose address is taken outside the vector table
    address_taken_from: dict[int, str]  # one way each was found
    vector: list[int] = field(default_factory=list)  # vector table words (word 0 = initial SP)
    stack_start: int | None = None
    stack_end: int | None = None
    task_names: dict[int, str] = field(default_factory=dict)  # task poll start -> short task name
    warnings: list[str] = field(default_factory=list)
    data_symbols: list[tuple[int, int, str]] = field(default_factory=list)  # (address, size, name): RAM objects

    def data_symbol_below(self, top: int) -> tuple[int, int, str] | None:
        """The data symbol whose bytes end at or contain ``top - 1`` (a stack's top is its end)."""
        hits = [s for s in self.data_symbols if s[1] > 0 and s[0] < top <= s[0] + s[1]]
        return min(hits, key=lambda s: s[1]) if hits else None

    def containing(self, addr: int) -> FuncInfo | None:
        a = addr & ~1
        if a in self.funcs:
            return self.funcs[a]
        for f in self.funcs.values():  # rare: only for odd targets
            if f.start <= a < f.end:
                return f
        return None


def build_program(objdump_text: str, symbols=None, extra_words=(), vector=(), stack=(None, None),
                  dwarf_names=None, data_symbols=()) -> Program:
    """Build the analysed program.

    ``symbols``: [(address, size, raw name, is_global)] of the functions; None = take the objdump labels (for
    tests: each label starts a function running to the next label). ``extra_words``: 32-bit words of the loaded
    non-code sections (.rodata, .data, …) scanned for function addresses; the .text literal pools come from the
    objdump text itself. ``vector``: the vector table words. ``dwarf_names``: {raw symbol: DWARF DW_AT_name}.
    ``data_symbols``: [(address, size, raw name)] of the sized data objects in writable memory (where a separate
    stack can be)."""
    insns, labels, data = parse_objdump(objdump_text)
    if symbols is None:
        symbols = []
        starts = sorted(a for a, ns in labels.items() if any(not x.startswith("$") for x in ns))
        for k, a in enumerate(starts):
            end = starts[k + 1] if k + 1 < len(starts) else (insns[-1].addr + 4 if insns else a)
            for nm in labels[a]:
                if not nm.startswith("$"):
                    symbols.append((a, end - a, nm, True))
    by_addr: dict[int, list] = {}
    for a, size, raw, glob in symbols:
        by_addr.setdefault(a & ~1, []).append((size, raw, glob))
    raw_names = sorted({raw for v in by_addr.values() for _, raw, _ in v})
    dem = demangle_all(raw_names)
    starts = sorted(by_addr)
    text_end = insns[-1].addr + 4 if insns else 0
    funcs: dict[int, FuncInfo] = {}
    preferred = ("Reset", "DefaultHandler", "HardFault", "main")
    for k, a in enumerate(starts):
        cands = by_addr[a]
        size = max(s for s, _, _ in cands)
        nxt = starts[k + 1] if k + 1 < len(starts) else max(text_end, a + size)
        end = a + size if size > 0 else nxt
        cands.sort(key=lambda c: (dem[c[1]] not in preferred, c[0] == 0, not c[2], len(c[1])))
        raw = cands[0][1]
        funcs[a] = FuncInfo(a, end, dem[raw], raw, aliases=sorted({dem[c[1]] for c in cands} - {dem[raw]}))

    # Assign instructions to functions (by extent).
    prog = Program(funcs, set(), {}, list(vector), stack[0], stack[1])
    dnames = demangle_all([n for _, _, n in data_symbols])
    prog.data_symbols = [(a, sz, dnames.get(n, n)) for a, sz, n in data_symbols]
    starts_set = set(funcs)
    per: dict[int, list[Insn]] = {a: [] for a in funcs}
    order = sorted(funcs)
    j = 0
    orphans = 0
    for ins in insns:
        while j + 1 < len(order) and ins.addr >= order[j + 1]:
            j += 1
        if order and order[j] <= ins.addr < funcs[order[j]].end:
            per[order[j]].append(ins)
        elif not is_padding(ins):
            orphans += 1
    if orphans:
        prog.warnings.append(f"{orphans} instructions lie outside every function symbol and were not analysed")

    for a, f in funcs.items():
        analyse_function(f, per[a], data, lambda x: x in starts_set)

    # Address-taken functions: literal words in .text (objdump data lines), words of the other loaded sections,
    # movw/movt pairs and adr in code.
    def take(v: int, how: str):
        if v & 1 and (v & ~1) in funcs:
            a = v & ~1
            if a not in prog.address_taken:
                prog.address_taken.add(a)
                prog.address_taken_from[a] = how

    blob = bytearray()
    blob_start = None
    for a in sorted(data):
        if blob_start is None or a != blob_start + len(blob):
            _scan_words(blob_start, blob, take, "literal in .text")
            blob, blob_start = bytearray(), a
        blob += data[a]
    _scan_words(blob_start, blob, take, "literal in .text")
    for w in extra_words:
        take(w, "word in a data section")
    for a, f in funcs.items():
        lo: dict[str, int] = {}
        for ins in per[a]:
            ops = split_ops(ins.ops)
            b = ins.mnem.split(".")[0]
            if b[:4] in ("movw", "movt") and b[4:] in CONDS:
                b = b[:4]  # predicated in an IT block
            if b == "movw" and len(ops) == 2 and imm(ops[1]) is not None:
                lo[norm_reg(ops[0])] = imm(ops[1])
            elif b == "movt" and len(ops) == 2 and imm(ops[1]) is not None and norm_reg(ops[0]) in lo:
                take(lo.pop(norm_reg(ops[0])) | (imm(ops[1]) << 16), f"movw/movt in {f.name}")
            elif b == "adr" and ins.target is not None:
                take(ins.target | 1, f"adr in {f.name}")
            elif b == "adr" and len(ops) == 2:
                m = re.fullmatch(r"#(-?\d+)", ops[1])
                if m:
                    take(((ins.addr + 4) & ~3) + int(m.group(1)) | 1, f"adr in {f.name}")

    # Task names from DWARF where available.
    for a, f in funcs.items():
        if TASK_POLL_RE.search(f.name):
            prog.task_names[a] = task_label((dwarf_names or {}).get(f.raw), f.name)
    return prog


def _scan_words(start, blob, take, how):
    if start is None:
        return
    k = (-start) % 4
    while k + 4 <= len(blob):
        take(int.from_bytes(blob[k : k + 4], "little"), how)
        k += 4


# --------------------------------------------------------------------------------------------------------------------
# Call graph and worst case

TASKS = -1  # key of the executor's bound (the deepest task poll) in Result.worst
INDIRECT = -2  # key of the address-taken bound in Result.worst


@dataclass
class Edge:
    to: int  # callee start
    held: int  # caller's SP offset at the call
    kind: str  # "call", "tail", "pointer" (indirect, address-taken), "executor" (task poll)
    site: Site | None


@dataclass
class Result:
    worst: dict[int, int]  # function start -> worst-case bytes from its entry (TASKS/INDIRECT: the two bounds)
    path: dict[int, list[tuple[int, int, str | None]]]  # [(function, bytes held (leaf: frame), how it was called)]
    cycles: list[dict]
    unbounded_reached: dict[int, list[str]]
    unknown_calls: list[str]
    edges: dict[int, list[Edge]]
    executor_funcs: list[int]
    task_targets: list[int]
    indirect_targets: list[int]


def solve(prog: Program, roots: list[int], allow: list[str]) -> Result:
    """Worst case from each function the roots reach. An indirect call becomes one edge per possible target
    (the task polls for the executor, the address-taken functions otherwise), so a cycle through a function
    pointer is a cycle of real functions."""
    funcs = prog.funcs
    executor = sorted(a for a, f in funcs.items() if EXECUTOR_RE.search(f.name))
    tasks = sorted(prog.task_names)
    task_targets = tasks + sorted(a for a, f in funcs.items() if POLL_EXITED_RE.search(f.name))
    indirect_targets = sorted(prog.address_taken - set(tasks))
    edges: dict[int, list[Edge]] = {}
    unknown_calls = []
    for a, f in funcs.items():
        es = []
        for s in f.sites:
            if s.kind in ("call", "tail"):
                g = prog.containing(s.target)
                if g is None:
                    unknown_calls.append(f"{f.name}: {s.text}")
                    continue
                if g.start != (s.target & ~1) and g is not f:
                    prog.warnings.append(f"{f.name} calls into the middle of {g.name}: {s.text}")
                es.append(Edge(g.start, s.offset, s.kind, s))
            elif a in executor:
                es += [Edge(t, s.offset, "executor", s) for t in task_targets]
            else:
                es += [Edge(t, s.offset, "pointer", s) for t in indirect_targets]
        edges[a] = es

    # Tarjan's SCCs (iterative) over what the roots reach; they come out callees first.
    index: dict[int, int] = {}
    low: dict[int, int] = {}
    on: set[int] = set()
    stack: list[int] = []
    sccs: list[list[int]] = []

    def visit(v: int):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        return (v, iter(edges.get(v, [])))

    for r in roots:
        if r in index:
            continue
        work = [visit(r)]
        while work:
            v, it = work[-1]
            descended = False
            for e in it:
                if e.to not in index:
                    work.append(visit(e.to))
                    descended = True
                    break
                if e.to in on:
                    low[v] = min(low[v], index[e.to])
            if descended:
                continue
            work.pop()
            if work:
                u = work[-1][0]
                low[u] = min(low[u], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                sccs.append(comp)

    worst: dict[int, int] = {}
    choice: dict[int, list[tuple[int, int, str | None]]] = {}
    cycles = []

    def frame(v: int) -> int:
        return funcs[v].frame

    def extend(v: int, e: Edge, sub: list) -> list:
        return [(v, e.held, None)] + [(sub[0][0], sub[0][1], e.kind)] + sub[1:]

    for comp in sccs:
        cset = set(comp)
        cyclic = len(comp) > 1 or any(e.to == comp[0] for e in edges.get(comp[0], []))
        if not cyclic:
            v = comp[0]
            best, path = frame(v), [(v, frame(v), None)]
            for e in edges.get(v, []):
                if e.held + worst[e.to] > best:
                    best, path = e.held + worst[e.to], extend(v, e, choice[e.to])
            worst[v], choice[v] = best, path
            continue
        # Allowed when every cycle passes through an allowed function: without them, the rest is acyclic.
        ok_nodes = {v for v in comp if any(s in funcs[v].name for s in allow)}
        rest = _cyclic_parts({v: [e.to for e in edges.get(v, []) if e.to in cset and e.to not in ok_nodes]
                              for v in comp if v not in ok_nodes})
        kinds = {e.kind for v in comp for e in edges.get(v, []) if e.to in cset}
        cycles.append({
            "functions": sorted(funcs[v].name for v in comp),
            "through_function_pointer": bool(kinds & {"pointer", "executor"}),
            "allowed": not rest,
            "allowed_by": sorted(funcs[v].name for v in ok_nodes),
            "not_allowed": [sorted(funcs[v].name for v in part) for part in rest],
            "example": [funcs[v].name for v in _example_cycle(comp, edges, rest[0] if rest else None)],
            "bound": "one pass: the calls that close a cycle (back edges of a depth-first search from the entry, "
                     "deepest calls first) are not counted",
        })
        # The bound from each entry: drop the back edges of a DFS from it, then the deepest path of what is left
        # (a DAG). Calls leaving the component use the callees' final figures.
        inner = {v: sorted((e for e in edges.get(v, []) if e.to in cset), key=lambda e: -(e.held + frame(e.to)))
                 for v in comp}
        results = {}
        for entry in comp:
            state = {entry: 1}
            kept: dict[int, list[Edge]] = {v: [] for v in comp}
            post = []
            work = [(entry, iter(inner[entry]))]
            while work:
                v, it = work[-1]
                for e in it:
                    if state.get(e.to) == 1:
                        continue  # closes a cycle
                    kept[v].append(e)
                    if e.to not in state:
                        state[e.to] = 1
                        work.append((e.to, iter(inner[e.to])))
                        break
                else:
                    work.pop()
                    state[v] = 2
                    post.append(v)
            val: dict[int, tuple[int, list]] = {}
            for v in post:
                best, path = frame(v), [(v, frame(v), None)]
                for e in edges.get(v, []):
                    if e.to not in cset and e.held + worst[e.to] > best:
                        best, path = e.held + worst[e.to], extend(v, e, choice[e.to])
                for e in kept[v]:
                    if e.held + val[e.to][0] > best:
                        best, path = e.held + val[e.to][0], extend(v, e, val[e.to][1])
                val[v] = (best, path)
            results[entry] = val[entry]
        for v in comp:
            worst[v], choice[v] = results[v]

    worst[TASKS] = max((worst.get(t, 0) for t in task_targets), default=0)
    worst[INDIRECT] = max((worst.get(t, 0) for t in indirect_targets), default=0)
    reached = set(index)
    unbounded_reached = {v: funcs[v].unbounded for v in reached if funcs[v].unbounded}
    return Result(worst, choice, cycles, unbounded_reached, unknown_calls, edges, executor, task_targets,
                  indirect_targets)


def _cyclic_parts(graph: dict[int, list[int]]) -> list[list[int]]:
    """The cyclic strongly connected components of a small graph {node: [successors]} (recursive Tarjan)."""
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    index, low, on, st, out = {}, {}, set(), [], []

    def visit(v):
        index[v] = low[v] = len(index)
        st.append(v)
        on.add(v)
        for w in graph.get(v, []):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = st.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph.get(v, []):
                out.append(comp)

    for v in graph:
        if v not in index:
            visit(v)
    return out


def _example_cycle(comp: list[int], edges, within: list[int] | None) -> list[int]:
    """One shortest cycle (breadth-first from each node), inside ``within`` when given, for the report."""
    nodes = set(within or comp)
    best: list[int] | None = None
    for s in sorted(nodes):
        prev: dict[int, int | None] = {s: None}
        frontier, last = [s], None
        while frontier and last is None:
            nxt = []
            for v in frontier:
                for e in edges.get(v, []):
                    w = e.to
                    if w == s:
                        last = v
                        break
                    if w in nodes and w not in prev:
                        prev[w] = v
                        nxt.append(w)
                if last is not None:
                    break
            frontier = nxt
        if last is not None:
            cyc = [last]
            while cyc[-1] != s:
                cyc.append(prev[cyc[-1]])
            cyc.reverse()
            if best is None or len(cyc) < len(best):
                best = cyc
            if len(best) <= 2:
                break
    return best + best[:1] if best else []


# --------------------------------------------------------------------------------------------------------------------
# ELF


def load_elf(path: str):
    """Symbols, loaded-section words, vector table and stack symbols, DWARF names of the task poll functions."""
    from elftools.elf.elffile import ELFFile
    from elftools.elf.sections import SymbolTableSection

    with open(path, "rb") as fh:
        elf = ELFFile(fh)
        exec_idx, secs = set(), {}
        for i, s in enumerate(elf.iter_sections()):
            secs[s.name] = s
            if s["sh_flags"] & 0x4:  # SHF_EXECINSTR
                exec_idx.add(i)
        symtab = elf.get_section_by_name(".symtab")
        if not isinstance(symtab, SymbolTableSection):
            raise SystemExit("stack.py: the ELF has no symbol table (it must be built with symbols kept)")
        write_idx = {i for i, s in enumerate(elf.iter_sections()) if s["sh_flags"] & 0x3 == 0x3}  # ALLOC|WRITE
        funcs, syms, data_syms = [], {}, []
        for s in symtab.iter_symbols():
            syms.setdefault(s.name, s["st_value"])
            if s["st_info"]["type"] == "STT_FUNC" and s["st_shndx"] in exec_idx and s.name:
                funcs.append((s["st_value"], s["st_size"], s.name, s["st_info"]["bind"] == "STB_GLOBAL"))
            elif (s["st_info"]["type"] in ("STT_OBJECT", "STT_NOTYPE") and s["st_size"] > 0 and s.name
                  and s["st_shndx"] in write_idx):
                data_syms.append((s["st_value"], s["st_size"], s.name))
        words = []
        vector = []
        for s in elf.iter_sections():
            if s["sh_type"] != "SHT_PROGBITS" or not s["sh_flags"] & 0x2 or s["sh_flags"] & 0x4:
                continue  # loaded (SHF_ALLOC) data only; .text literals come from the disassembly
            d = s.data()
            ws = [int.from_bytes(d[k : k + 4], "little") for k in range(0, len(d) - 3, 4)]
            if s.name == ".vector_table":
                vector = ws
            else:
                words += ws
        # DWARF names of the task poll functions (legacy mangling drops TaskStorage's generic argument).
        want = {raw for _, _, raw, _ in funcs if "TaskStorage" in raw}
        dwarf_names = {}
        if want and elf.has_dwarf_info():
            try:
                dw = elf.get_dwarf_info()
                for cu in dw.iter_CUs():
                    for die in cu.iter_DIEs():
                        if die.tag != "DW_TAG_subprogram":
                            continue
                        ln = die.attributes.get("DW_AT_linkage_name")
                        nm = die.attributes.get("DW_AT_name")
                        if ln and nm:
                            lv = ln.value.decode(errors="replace")
                            if lv in want and lv not in dwarf_names:
                                dwarf_names[lv] = nm.value.decode(errors="replace")
                    if len(dwarf_names) == len(want):
                        break
            except Exception as e:  # noqa: BLE001 — names are cosmetic; never fail the check on them
                print(f"stack.py: warning: DWARF not readable ({e}); tasks named by hash", file=sys.stderr)
    return funcs, words, vector, (syms.get("_stack_start"), syms.get("_stack_end")), dwarf_names, data_syms


def run_objdump(path: str) -> str:
    tool = os.environ.get("LLVM_OBJDUMP") or shutil.which("llvm-objdump")
    if not tool:
        for v in range(25, 11, -1):
            tool = shutil.which(f"llvm-objdump-{v}")
            if tool:
                break
    if not tool:
        raise SystemExit("stack.py: llvm-objdump not found (Debian: apt-get install llvm)")
    res = subprocess.run([tool, "-d", "--no-show-raw-insn", path], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"stack.py: llvm-objdump failed: {res.stderr.strip()}")
    return res.stdout


def load_boot_priorities(path: str) -> dict:
    """Interrupt priorities from the JSON that ``boot.py ELF --json FILE`` writes: ``figures.nvic_enabled`` =
    [{"irq", "priority" (raw 8-bit NVIC_IPR), "handler", ...}] for every IRQ enabled when the emulated boot ended;
    optionally ``figures.system_priorities`` = {exception name or number: raw 8-bit SHPR priority} (boot.py does
    not write it today: SysTick is then a level of its own above every IRQ).

    Returns {"source", "elf_sha256", "irq": {irq: {"priority", "handler"}}, "system": {exception number: priority}};
    raises SystemExit on a file that is not such a JSON."""
    try:
        with open(path) as fh:
            doc = json.load(fh)
    except (OSError, ValueError) as e:
        raise SystemExit(f"stack.py: --boot-json {path}: {e}") from None
    fig = doc.get("figures") if isinstance(doc, dict) else None
    nv = fig.get("nvic_enabled") if isinstance(fig, dict) else None
    if not isinstance(nv, list):
        raise SystemExit(f"stack.py: --boot-json {path}: no figures.nvic_enabled (not a boot.py --json file?)")
    irq = {}
    for ent in nv:
        try:
            n, pr = int(ent["irq"]), int(ent["priority"])
        except (KeyError, TypeError, ValueError):
            raise SystemExit(f"stack.py: --boot-json {path}: bad nvic_enabled entry {ent!r}") from None
        if not 0 <= pr <= 255:
            raise SystemExit(f"stack.py: --boot-json {path}: IRQ {n} priority {pr} is not an 8-bit value")
        irq[n] = {"priority": pr, "handler": ent.get("handler")}
    system = {}
    by_name = {v: k for k, v in EXC_NAMES.items()}
    for k, v in (fig.get("system_priorities") or {}).items():
        n = by_name.get(k) if not str(k).isdigit() else int(k)
        if n is not None and n >= 4 and isinstance(v, int) and 0 <= v <= 255:
            system[n] = v
    run = doc.get("run") if isinstance(doc.get("run"), dict) else {}
    return {"source": path, "elf_sha256": run.get("sha256"), "irq": irq, "system": system}


# --------------------------------------------------------------------------------------------------------------------
# Report


def analyse(prog: Program, allow: list[str], max_percent: float, max_frame: int,
            priorities: dict | None = None) -> dict:
    """The report. ``priorities``: from ``load_boot_priorities`` (None: not known, every handler a level)."""
    funcs = prog.funcs
    errors: list[str] = []
    region = None
    if prog.stack_start is not None and prog.stack_end is not None:
        region = prog.stack_start - prog.stack_end

    # Roots.
    vec = prog.vector
    handlers: dict[int, list[str]] = {}  # handler start -> vector names
    handler_vecs: dict[int, list[int]] = {}  # handler start -> vector indices
    for i, w in enumerate(vec[1:], start=1):
        if w == 0 or i == 1:
            continue
        f = prog.containing(w)
        if f is None:
            prog.warnings.append(f"vector {i} ({w:#010x}) points outside every function")
            continue
        label = EXC_NAMES.get(i, f"IRQ {i - 16}" if i >= 16 else f"exception {i}")
        handlers.setdefault(f.start, []).append(label)
        handler_vecs.setdefault(f.start, []).append(i)
    reset = prog.containing(vec[1]) if len(vec) > 1 else None
    if reset is None:
        reset = next((f for f in funcs.values() if f.name == "Reset"), None)
    hardfault = prog.containing(vec[3]) if len(vec) > 3 and vec[3] else None
    nmi = prog.containing(vec[2]) if len(vec) > 2 and vec[2] else None

    roots: list[dict] = []
    if reset:
        roots.append({"kind": "thread", "name": "Reset (thread: init, main, tasks)", "func": reset.start})
    for a in sorted(prog.task_names, key=lambda a: prog.task_names[a]):
        roots.append({"kind": "task", "name": f"task {prog.task_names[a]}", "func": a})
    default_like = {a for a, f in funcs.items() if f.name.startswith("DefaultHandler")
                    or any(x.startswith("DefaultHandler") for x in f.aliases)}
    def handler_order(kv):
        a = kv[0]
        return (not (hardfault and a == hardfault.start), a in default_like, funcs[a].name)

    for a, names in sorted(handlers.items(), key=handler_order):
        f = funcs[a]
        if a in default_like:
            nm = f"DefaultHandler ({len(names)} vectors)"
        elif re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", f.name):
            nm = f.name if names == [f.name] else f"{f.name} ({', '.join(names)})"
        else:
            nm = f"{', '.join(names)} ({short_name(f.name, 40)})"
        kind = "hardfault" if hardfault and a == hardfault.start else "handler"
        roots.append({"kind": kind, "name": nm, "func": a, "vectors": names})

    res = solve(prog, [r["func"] for r in roots], allow)

    def path_json(v: int) -> list[dict]:
        out = []
        for node, held, via in res.path.get(v, []):
            f = funcs[node]
            ent = {"function": f.name, "frame": f.frame, "bytes": held}
            if via:
                ent["called_by"] = via  # call, tail, pointer (address-taken bound), executor (task poll)
            if node in prog.task_names:
                ent["task"] = prog.task_names[node]
            out.append(ent)
        return out

    for r in roots:
        r["function"] = funcs[r["func"]].name
        r["worst_bytes"] = res.worst[r["func"]]
        r["percent_of_region"] = round(100.0 * r["worst_bytes"] / region, 1) if region else None
        r["path"] = path_json(r["func"])
        del r["func"]

    # Separate stacks: a HardFault or NMI handler that moves MSP at its entry (``_entry_stack_switch``).
    reached = {v for v in res.worst if v >= 0}
    callees = {e.to for v in reached for e in res.edges.get(v, [])}
    separate: dict[int, dict] = {}  # root start -> the stack it runs on
    for a in sorted(reached):
        f = funcs[a]
        if not f.stack_switch:
            continue
        sw = f.stack_switch
        is_root = (hardfault and a == hardfault.start) or (nmi and a == nmi.start)
        why = None
        sym = prog.data_symbol_below(sw["value"])
        if not is_root or (hardfault and nmi and hardfault.start == nmi.start):
            why = "only the HardFault or NMI handler may move MSP to a stack of its own"
        elif a in callees:
            why = "the function that moves MSP is also called (not only entered as an exception)"
        elif any(a in handler_vecs and v not in (2, 3) for v in handler_vecs.get(a, [])):
            why = "the handler that moves MSP is also the handler of a configurable-priority vector"
        elif sym is None:
            why = f"the new SP {sw['value']:#010x} is not the top of (or inside) any data symbol"
        elif (prog.stack_end is not None and prog.stack_start is not None
              and sym[0] < prog.stack_start and prog.stack_end < sym[0] + sym[1]):
            why = f"the new stack {sym[2]} overlaps the main stack region"
        if why:
            res.unbounded_reached.setdefault(a, []).insert(0, f"stack pointer switched (msp): {why}: {sw['text']}")
            continue
        usable = sw["value"] - sym[0]
        separate[a] = {"root": "HardFault" if hardfault and a == hardfault.start else "NMI", "function": f.name,
                       "symbol": sym[2], "address": f"{sym[0]:#010x}", "symbol_bytes": sym[1],
                       "top": f"{sw['value']:#010x}", "bytes": usable, "handler_bytes": res.worst[a]}
        if sw["value"] % 8:
            prog.warnings.append(f"{f.name} moves MSP to {sw['value']:#010x}, not 8-byte aligned (AAPCS)")
    # What preempts a handler on a stack of its own runs on that stack: NMI preempts HardFault.
    for a, st in separate.items():
        st["nmi_bytes"] = 0
        if st["root"] == "HardFault" and nmi and nmi.start != a:
            if nmi.start in separate:
                st["nmi_bytes"] = EXC_ENTRY  # only the NMI's hardware frame; its handler moves to its own stack
                if separate[nmi.start]["symbol"] == st["symbol"]:
                    errors.append(f"HardFault and NMI both move MSP to {st['symbol']}: an NMI during the "
                                  "HardFault handler would overwrite its stack")
            else:
                st["nmi_bytes"] = res.worst[nmi.start] + EXC_ENTRY
        st["worst_bytes"] = st["handler_bytes"] + st["nmi_bytes"]
        st["percent"] = round(100.0 * st["worst_bytes"] / st["bytes"], 1) if st["bytes"] else None
        st["limit_percent"] = max_percent
        if st["percent"] is None or st["percent"] > max_percent:
            errors.append(f"{st['root']} stack {st['symbol']}: worst case {st['worst_bytes']} B is "
                          f"{st['percent']}% of its {st['bytes']} B (limit {max_percent}%)")

    # Total for the MSP: thread + one handler per preemption level (+ entry) + HardFault + NMI.
    levels = []
    if reset:
        levels.append({"level": "thread mode (Reset)", "short": "thread", "bytes": res.worst[reset.start],
                       "function": reset.name})
    prio_notes: list[str] = []
    groups: dict[tuple, list[tuple[int, int, int | None]]] = {}  # level key -> [(handler, vector, raw priority)]
    sys_prio = (priorities or {}).get("system", {})
    irq_prio = (priorities or {}).get("irq", {})
    unknown_vecs = []
    for n, ent in sorted(irq_prio.items()):  # the boot JSON must describe this ELF's vector table
        w = vec[16 + n] if 16 + n < len(vec) else 0
        f = prog.containing(w) if w else None
        if f is None:
            prog.warnings.append(f"boot JSON: IRQ {n} is enabled but has no handler in this ELF's vector table")
        elif ent.get("handler") and ent["handler"] not in {f.name, f.raw, *f.aliases}:
            prog.warnings.append(f"boot JSON: IRQ {n}'s handler is {ent['handler']}, this ELF's vector points to "
                                 f"{f.name} (JSON of another build?)")
    for a in sorted(handler_vecs):
        for v in handler_vecs[a]:
            if v in (2, 3):
                continue  # NMI, HardFault: fixed priorities above every configurable level
            if priorities is None:
                key = (1, 0, a)  # not known: every handler a level of its own
                raw = None
            elif v >= 16 and (v - 16) in irq_prio:
                raw = irq_prio[v - 16]["priority"]
                key = (0, raw >> PREEMPT_SHIFT, 0)
            elif v < 16 and v in sys_prio:
                raw = sys_prio[v]
                key = (0, raw >> PREEMPT_SHIFT, 0)
            elif v == 15:
                key, raw = (-1, 0, 0), None  # SysTick not known: a level of its own above every IRQ
            else:
                key, raw = (0, 0, 0), 0  # not enabled at the boot's end / not known: the reset value, 0
                unknown_vecs.append(v)
            groups.setdefault(key, []).append((a, v, raw))
    if priorities is not None and unknown_vecs:
        prio_notes.append(f"{len(unknown_vecs)} vectors with a handler but no priority in the boot JSON (not "
                          "enabled when the boot ended, or system exceptions) are taken at priority 0, the reset "
                          "value, the highest configurable level")
    for key in sorted(groups):
        members = groups[key]
        b, a = max((res.worst[a], a) for a, _, _ in members)
        names = sorted({funcs[x].name for x, _, _ in members})
        vecs = sorted({v for _, v, _ in members})
        if key[0] == 1:
            label, short = f"handler {short_name(funcs[a].name, 24)} (priority unknown) + entry", "handler"
            pre = raw = None
        elif key[0] == -1:
            label, short = "SysTick (priority unknown: above every IRQ) + entry", "SysTick"
            pre = raw = None
        else:
            pre = key[1]
            raws = sorted({r for _, _, r in members if r is not None})
            raw = raws[0] if len(raws) == 1 else raws
            pr = ", ".join(f"{r:#04x}" for r in raws)
            unset = any(v in unknown_vecs for _, v, _ in members)
            label = (f"level {pre} ({pr}{', unset = reset value' if unset else ''}): "
                     f"{len(names)} handler{'s' if len(names) > 1 else ''} + entry")
            short = f"level {pre}"
        levels.append({"level": label, "short": short, "bytes": b + EXC_ENTRY, "function": funcs[a].name,
                       "handler_bytes": b, "entry_bytes": EXC_ENTRY, "preemption_level": pre, "priority": raw,
                       "handlers": names,
                       "vectors": [EXC_NAMES.get(v, f"IRQ {v - 16}" if v >= 16 else f"exception {v}") for v in vecs]})
    if hardfault:
        if hardfault.start in separate:
            st = separate[hardfault.start]
            levels.append({"level": f"HardFault exception entry (handler on {short_name(st['symbol'], 20)})",
                           "short": "HardFault entry", "bytes": EXC_ENTRY, "function": hardfault.name,
                           "handler_bytes": 0, "entry_bytes": EXC_ENTRY, "stack": st["symbol"]})
        else:
            b = res.worst[hardfault.start]
            levels.append({"level": "HardFault (may preempt a handler) + exception entry", "short": "HardFault",
                           "bytes": b + EXC_ENTRY,
                           "function": hardfault.name, "handler_bytes": b, "entry_bytes": EXC_ENTRY})
    if nmi and (not hardfault or nmi.start != hardfault.start):
        b = 0 if nmi.start in separate else res.worst[nmi.start]
        levels.append({"level": "NMI (preempts everything) + exception entry"
                       + (f" (handler on {separate[nmi.start]['symbol']})" if nmi.start in separate else ""),
                       "short": "NMI", "bytes": b + EXC_ENTRY,
                       "function": nmi.name, "handler_bytes": b, "entry_bytes": EXC_ENTRY})
    total = sum(lv["bytes"] for lv in levels)
    pct = round(100.0 * total / region, 1) if region else None
    priority_info = {"known": priorities is not None,
                     "source": (priorities or {}).get("source"),
                     "preemption_shift": PREEMPT_SHIFT,
                     "irq": {str(n): v for n, v in sorted(irq_prio.items())},
                     "system": {EXC_NAMES.get(n, str(n)): v for n, v in sorted(sys_prio.items())}}

    # Frames.
    def shown(f: FuncInfo) -> str:
        return f"{f.name} [task {prog.task_names[f.start]}]" if f.start in prog.task_names else f.name

    largest = max(funcs.values(), key=lambda f: f.frame) if funcs else None
    over = sorted((f for f in funcs.values() if f.frame > max_frame), key=lambda f: -f.frame)

    # Indirect call accounting.
    sites = []
    for a in sorted(funcs):
        for s in funcs[a].sites:
            if s.kind in ("indirect", "indirect-tail"):
                cls = "executor-task-poll" if a in res.executor_funcs else "address-taken"
                insn = re.sub(r"\s+", " ", s.text.split(":", 1)[-1]).strip()
                sites.append({"function": funcs[a].name, "address": f"{s.addr:#x}", "instruction": insn,
                              "class": cls, "reached": a in reached})
    task_bound = max(((res.worst.get(t, 0), t) for t in res.task_targets if t in res.worst), default=(0, None))
    ind_bound = max(((res.worst.get(t, 0), t) for t in res.indirect_targets if t in res.worst), default=(0, None))
    indirect = {
        "sites": len(sites),
        "sites_reached": sum(1 for s in sites if s["reached"]),
        "executor_sites": sum(1 for s in sites if s["class"] == "executor-task-poll"),
        "executor_functions": [funcs[a].name for a in res.executor_funcs],
        "executor_targets": [
            {"function": funcs[t].name, "task": prog.task_names.get(t), "worst_bytes": res.worst.get(t)}
            for t in res.task_targets
        ],
        "executor_bound": {"bytes": task_bound[0], "function": funcs[task_bound[1]].name if task_bound[1] else None},
        "address_taken_sites": sum(1 for s in sites if s["class"] == "address-taken"),
        "address_taken_functions": len(res.indirect_targets),
        "address_taken_bound": {"bytes": ind_bound[0],
                                "function": funcs[ind_bound[1]].name if ind_bound[1] is not None else None},
        "address_taken_list": [
            {"function": funcs[t].name, "found_by": prog.address_taken_from.get(t), "worst_bytes": res.worst.get(t)}
            for t in res.indirect_targets
        ],
        "site_list": sites,
    }
    if not res.executor_funcs and prog.task_names:
        prog.warnings.append("no embassy executor function found: task polls are reached only as address-taken")

    # Checks.
    if region is None:
        errors.append("no _stack_start/_stack_end symbols: stack region unknown")
    elif pct is not None and pct > max_percent:
        errors.append(f"worst-case stack {total} B is {pct}% of the {region} B stack region (limit {max_percent}%)")
    for f in over:
        errors.append(f"frame of {shown(f)} is {f.frame} B (limit {max_frame} B)"
                      + ("" if f.start in reached else " [not reached from any root]"))
    for c in res.cycles:
        if not c["allowed"]:
            errors.append(
                f"recursion not allowed among {sum(len(p) for p in c['not_allowed'])} functions"
                + (" (the cycle runs through function pointers)" if c["through_function_pointer"] else "")
                + ", e.g. " + " -> ".join(short_name(x, 50) for x in c["example"])
                + "; if intended, --allow-recursion SUBSTRING for a function every such cycle passes through")
    for v, why in sorted(res.unbounded_reached.items()):
        errors.append(f"unbounded frame in {funcs[v].name}: {why[0]}")
    for u in res.unknown_calls:
        errors.append(f"call to an address in no function: {u}")

    return {
        "region": {"stack_end": prog.stack_end, "stack_start": prog.stack_start, "bytes": region},
        "limits": {"max_percent": max_percent, "max_frame": max_frame, "allow_recursion": allow},
        "roots": roots,
        "total": {
            "bytes": total, "percent_of_region": pct, "levels": levels,
            "assumptions": [
                "one stack (MSP) for thread mode and every exception, except a HardFault/NMI handler that moves MSP "
                "to a stack of its own at its entry (its hardware frame still lands on the MSP)",
                f"exception entry {EXC_ENTRY} B: 26-word frame with the FPU on (lazy stacking reserves S0-S15, FPSCR)"
                " + 4 B alignment pad",
                ("handlers nest once per distinct preemption level (priority >> 4: AIRCR.PRIGROUP 0, 4 priority "
                 "bits); handlers of one level do not nest among themselves" if priorities is not None else
                 "interrupt priorities not known (no --boot-json): every handler counted as a level of its own"),
                "a HardFault can preempt any handler (a fault inside an ISR); an NMI preempts everything, "
                "the HardFault handler included",
            ] + prio_notes,
            "priorities": priority_info,
            "separate_stacks": list(separate.values()),
        },
        "largest_frame": {"function": shown(largest), "bytes": largest.frame} if largest else None,
        "frames_over_limit": [{"function": shown(f), "bytes": f.frame, "reached": f.start in reached} for f in over],
        "indirect_calls": indirect,
        "cycles": res.cycles,
        "unbounded": [{"function": funcs[v].name, "reasons": why} for v, why in sorted(res.unbounded_reached.items())],
        "functions_analysed": len(funcs),
        "functions": [
            {"function": f.name, "address": f"{f.start:#x}", "frame": f.frame, "worst_bytes": res.worst.get(f.start),
             **({"task": prog.task_names[f.start]} if f.start in prog.task_names else {}),
             **({"aliases": f.aliases} if f.aliases else {}), **({"notes": f.notes} if f.notes else {})}
            for f in sorted(funcs.values(), key=lambda f: (-f.frame, f.start))
        ],
        "warnings": prog.warnings,
        "errors": errors,
        "ok": not errors,
    }


def _label(p: dict, width: int) -> str:
    if "task" in p:
        return f"poll[{p['task']}]"
    return short_name(p["function"], width)


def _abbrev_path(path: list[dict], n: int = 3, md: bool = False) -> str:
    """The path's largest contributors, in call order."""
    real = path
    top = sorted(range(len(real)), key=lambda k: -real[k]["bytes"])[:n]
    q = "`" if md else ""
    parts = [f"{q}{_label(real[k], 38)}{q} {real[k]['bytes']}" for k in sorted(top) if real[k]["bytes"] > 0]
    return f"{len(path)} deep: " + " > ".join(parts)


def text_report(rep: dict, elf: str) -> str:
    region = rep["region"]["bytes"]
    out = [f"Worst-case stack usage of {elf}"]
    if region is not None:
        out.append(f"stack region: {region} B (_stack_end {rep['region']['stack_end']:#010x} .. _stack_start "
                   f"{rep['region']['stack_start']:#010x})")
    out.append("")
    w = 44
    out.append(f"{'root':<{w}} {'worst B':>9} {'% region':>9}  deepest path (largest frames, B held)")
    out.append("-" * 120)
    for r in rep["roots"]:
        pct = f"{r['percent_of_region']:.1f}" if r["percent_of_region"] is not None else "-"
        out.append(f"{short_name(r['name'], w):<{w}} {r['worst_bytes']:>9} {pct:>9}  {_abbrev_path(r['path'])}")
    out.append("-" * 120)
    t = rep["total"]
    pi = t.get("priorities") or {}
    if pi.get("known"):
        out.append(f"interrupt priorities from {pi.get('source')}: one handler frame per preemption level "
                   f"(priority >> {pi.get('preemption_shift')}), highest first")
    else:
        out.append("interrupt priorities NOT KNOWN (no --boot-json): every handler counted as a level of its own")
    for lv in t["levels"]:
        out.append(f"  + {lv['level']:<56} {lv['bytes']:>9}  ({short_name(lv['function'], 50)})")
    pct = f"{t['percent_of_region']:.1f}" if t["percent_of_region"] is not None else "-"
    out.append(f"{'TOTAL (MSP)':<{w}} {t['bytes']:>9} {pct:>9}  limit {rep['limits']['max_percent']}% = "
               + (f"{int(region * rep['limits']['max_percent'] / 100)} B" if region else "?"))
    for st in t.get("separate_stacks", []):
        nm = f" + NMI {st['nmi_bytes']}" if st["nmi_bytes"] else ""
        spct = f"{st['percent']:.1f}" if st["percent"] is not None else "-"
        out.append(f"{(st['root'] + ' stack (' + short_name(st['symbol'], 24) + ')'):<{w}} {st['worst_bytes']:>9} "
                   f"{spct:>9}  of its {st['bytes']} B at {st['address']} (handler {st['handler_bytes']}{nm}); "
                   f"limit {st['limit_percent']}% = {int(st['bytes'] * st['limit_percent'] / 100)} B")
    lf = rep["largest_frame"]
    if lf:
        out.append(f"largest single frame: {lf['bytes']} B in {lf['function']} (limit {rep['limits']['max_frame']} B)")
    ic = rep["indirect_calls"]
    out.append("")
    out.append(f"indirect calls: {ic['sites']} sites ({ic['sites_reached']} reachable from a root)")
    exe = ", ".join(short_name(x, 60) for x in ic["executor_functions"]) or "none found"
    out.append(f"  {ic['executor_sites']} in the executor ({exe}):"
               f" bounded by the deepest of {len(ic['executor_targets'])} task polls/poll_exited = "
               f"{ic['executor_bound']['bytes']} B ({short_name(ic['executor_bound']['function'] or '-', 60)})")
    out.append(f"  {ic['address_taken_sites']} others: bounded by the deepest of {ic['address_taken_functions']} "
               f"address-taken functions = {ic['address_taken_bound']['bytes']} B "
               f"({short_name(ic['address_taken_bound']['function'] or '-', 60)})")
    if rep["cycles"]:
        out.append("")
        out.append("recursion (cycles in the call graph):")
        for c in rep["cycles"]:
            tag = "allowed; bound " + c["bound"] if c["allowed"] else "NOT ALLOWED"
            via = " through function pointers" if c["through_function_pointer"] else ""
            out.append(f"  a cycle{via} among {len(c['functions'])} functions ({tag})")
            out.append("    e.g. " + " -> ".join(short_name(x, 45) for x in c["example"]))
            if c["allowed_by"]:
                out.append(f"    every cycle passes through one of {len(c['allowed_by'])} allowed functions "
                           f"({', '.join(short_name(x, 40) for x in c['allowed_by'][:4])}"
                           + (", …" if len(c["allowed_by"]) > 4 else "") + ")")
            for part in c["not_allowed"]:
                shown = ", ".join(short_name(x, 45) for x in part[:8])
                out.append(f"    not allowed: {len(part)} functions: {shown}" + (", …" if len(part) > 8 else ""))
            out.append("    (full list in --json)")
    out.append("")
    out.append("deepest paths (frame B / B held while the next one runs; '*' = reached through a function pointer"
               " (address-taken bound), 'task' = polled by the executor):")
    for r in rep["roots"]:
        if r["kind"] in ("thread", "hardfault") or r["percent_of_region"] and r["percent_of_region"] >= 10:
            out.append(f"  {r['name']}: {r['worst_bytes']} B")
            for p in r["path"]:
                mark = "*" if p.get("called_by") == "pointer" else " "
                tag = f" [task {p['task']}]" if "task" in p else ""
                out.append(f"     {mark}{p['frame']:>7} / {p['bytes']:>7}  {short_name(p['function'], 90)}{tag}")
    for wmsg in rep["warnings"]:
        out.append(f"warning: {wmsg}")
    out.append("")
    if rep["errors"]:
        out.append("FAIL:")
        out += [f"  - {e}" for e in rep["errors"]]
    else:
        out.append(f"OK: worst case {t['bytes']} B = {pct}% of the stack region "
                   f"(limit {rep['limits']['max_percent']}%)")
    return "\n".join(out)


def markdown_report(rep: dict) -> str:
    region = rep["region"]["bytes"]
    out = [f"Stack region: {region} B. Exception entry counted at {EXC_ENTRY} B per level.", "",
           "| Root | Worst case (B) | % of region | Deepest frames (B held) |", "| --- | ---: | ---: | --- |"]
    for r in rep["roots"]:
        pct = f"{r['percent_of_region']:.1f}" if r["percent_of_region"] is not None else "–"
        out.append(f"| {r['name']} | {r['worst_bytes']} | {pct} | {_abbrev_path(r['path'], md=True)} |")
    t = rep["total"]
    pct = f"{t['percent_of_region']:.1f}" if t["percent_of_region"] is not None else "–"
    parts = " + ".join(f"{lv['bytes']} {lv['short']}" for lv in t["levels"])
    out.append(f"| **Total (MSP)** | **{t['bytes']}** | **{pct}** | {parts} "
               f"(exception levels include {EXC_ENTRY} B entry) |")
    for st in t.get("separate_stacks", []):
        spct = f"{st['percent']:.1f}" if st["percent"] is not None else "–"
        out.append(f"| {st['root']} stack (`{st['symbol']}`, {st['bytes']} B) | {st['worst_bytes']} | {spct} "
                   f"(of its own stack) | handler {st['handler_bytes']}"
                   + (f" + NMI {st['nmi_bytes']}" if st["nmi_bytes"] else "") + " |")
    lf = rep["largest_frame"]
    if lf:
        out += ["", f"Largest single frame: {lf['bytes']} B (`{short_name(lf['function'], 80)}`)."]
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Worst-case stack usage of the firmware ELF (see the module docstring).")
    ap.add_argument("elf")
    ap.add_argument("--json", metavar="PATH", help="write every figure as JSON")
    ap.add_argument("--markdown", action="store_true", help="also print a Markdown table for the docs")
    ap.add_argument("--max-percent", type=float, default=75.0, help="limit on the total, %% of the region (75)")
    ap.add_argument("--max-frame", type=int, default=8192, help="limit on any single frame, bytes (8192)")
    ap.add_argument("--min-region", type=int, default=0, metavar="BYTES",
                    help="fail if the stack region is smaller (the firmware's layout::MCU_STACK_LEN, which the host "
                         "tests run their tasks on)")
    ap.add_argument("--boot-json", metavar="FILE",
                    help="interrupt priorities from `boot.py ELF --json FILE` (figures.nvic_enabled): one handler "
                         "frame per preemption level; without it every handler counts as a level of its own")
    ap.add_argument("--allow-recursion", action="append", default=[], metavar="SUBSTRING",
                    help="accept recursion whose every cycle passes through a function whose name contains "
                         "SUBSTRING (repeatable); its bound is then one pass through the cycles")
    args = ap.parse_args(argv)
    if not os.path.isfile(args.elf):
        print(f"stack.py: no such ELF: {args.elf}", file=sys.stderr)
        return 2
    try:
        priorities = load_boot_priorities(args.boot_json) if args.boot_json else None
        funcs, words, vector, stack, dwarf_names, data_syms = load_elf(args.elf)
        prog = build_program(run_objdump(args.elf), funcs, words, vector, stack, dwarf_names, data_syms)
    except SystemExit as e:
        print(e, file=sys.stderr)
        return 2
    with open(args.elf, "rb") as fh:
        sha = hashlib.sha256(fh.read()).hexdigest()
    rep = analyse(prog, args.allow_recursion, args.max_percent, args.max_frame, priorities)
    if priorities is not None and priorities.get("elf_sha256") and priorities["elf_sha256"] != sha:
        rep["ok"] = False
        rep["errors"].append(f"--boot-json {args.boot_json} is of another ELF (sha256 "
                             f"{priorities['elf_sha256'][:12]}…, this one {sha[:12]}…): its priorities do not apply")
    if rep["region"]["bytes"] is not None and rep["region"]["bytes"] < args.min_region:
        rep["ok"] = False
        rep.setdefault("errors", []).append(
            f"stack region {rep['region']['bytes']} B is smaller than --min-region {args.min_region} B")
    rep = {"elf": args.elf, "sha256": sha, **rep}
    print(text_report(rep, args.elf))
    if args.markdown:
        print()
        print(markdown_report(rep))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rep, fh, indent=1)
    return 0 if rep["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
