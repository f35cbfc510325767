"""Unit tests of stack.py on small synthetic ``llvm-objdump -d --no-show-raw-insn`` listings.

Run with ``python3 -m pytest tools/fw-check`` or ``python3 tools/fw-check/test_stack.py``. Every test asserts exact
figures worked out by hand in its comments, so a wrong frame, edge or bound makes it fail.
"""

import os
import sys
import textwrap

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import stack  # noqa: E402


def asm(src: str) -> str:
    """Compact listing -> llvm-objdump's layout.

    ``08000000 <name>:`` lines are kept; ``8000000: mnem ops`` becomes `` 8000000:      \\tmnem\\tops``;
    ``8000010: .word 0x08000101`` becomes a data line with its raw bytes, as objdump prints literal pools."""
    out = []
    for line in textwrap.dedent(src).strip().splitlines():
        line = line.strip()
        if not line or line.endswith(">:"):
            out.append(line)
            continue
        addr, rest = line.split(":", 1)
        rest = rest.strip()
        if rest.startswith((".word", ".short", ".byte")):
            kind, val = rest.split()
            width = {".word": 4, ".short": 2, ".byte": 1}[kind]
            raw = int(val, 16).to_bytes(width, "little")
            out.append(f" {addr}:\t{' '.join(f'{b:02x}' for b in raw)}\t{kind}\t{val}")
        else:
            mnem, _, ops = rest.partition(" ")
            out.append(f" {addr}:      \t{mnem}\t{ops.strip()}")
    return "\n".join(out) + "\n"


def program(src: str, **kw) -> stack.Program:
    return stack.build_program(asm(src), **kw)


def by_name(prog: stack.Program, name: str) -> stack.FuncInfo:
    (f,) = [f for f in prog.funcs.values() if f.name == name]
    return f


# --------------------------------------------------------------------------------------------------------------------


def test_frame_push_vpush_sub():
    # 20 (5 regs) + 16 (4 regs) + 32 (4 d regs) + 8 (2 s regs) + 4096 + 12 = 4184; the epilogue undoes it all.
    prog = program("""
        08000000 <big>:
         8000000: push {r4, r5, r6, r7, lr}
         8000002: add r7, sp, #12
         8000004: push.w {r8, r9, r10, r11}
         8000008: vpush {d8, d9, d10, d11}
         800000c: vpush {s16, s17}
         8000010: sub.w sp, sp, #4096
         8000014: sub sp, #12
         8000016: movs r0, #0
         8000018: add sp, #12
         800001a: add.w sp, sp, #4096
         800001e: vpop {s16, s17}
         8000022: vpop {d8, d9, d10, d11}
         8000026: pop.w {r8, r9, r10, r11}
         800002a: pop {r4, r5, r6, r7, pc}
    """)
    f = by_name(prog, "big")
    assert f.frame == 20 + 16 + 32 + 8 + 4096 + 12 == 4184
    assert not f.unbounded
    assert not f.notes  # returns at offset 0


def test_frame_verbatim_objdump_lines():
    # Lines exactly as llvm-objdump 14 prints them (the broken firmware's main task): 20 + 16 + 39680 + 236.
    text = (
        "08010cd8 <embassy_executor::raw::TaskStorage$LT$F$GT$::poll::hb9ffa0981487723e>:\n"
        " 8010cd8:      \tpush\t{r4, r5, r6, r7, lr}\n"
        " 8010cda:      \tadd\tr7, sp, #12\n"
        " 8010cdc:      \tpush.w\t{r8, r9, r10, r11}\n"
        " 8010ce0:      \tsub.w\tsp, sp, #39680\n"
        " 8010ce4:      \tsub\tsp, #236\n"
        " 8010ce6:      \tldrb.w\tr1, [r0, #44]\n"
        " 8010cea:      \tlsls\tr1, r1, #31\n"
        " 8010cec:      \tbne.w\t0x8010cf4 <embassy_executor::raw::TaskStorage$LT$F$GT$::poll::hb9ffa0981487723e+0x1c> @ imm = #4\n"
        " 8010cf0:      \tbl\t0x8010d00 <leaf>        @ imm = #12\n"
        " 8010cf4:      \tsub.w\tsp, r7, #28\n"
        " 8010cf8:      \tpop.w\t{r8, r9, r10, r11}\n"
        " 8010cfc:      \tpop\t{r4, r5, r6, r7, pc}\n"
        "\n"
        "08010d00 <leaf>:\n"
        " 8010d00:      \tbx\tlr\n"
    )
    prog = stack.build_program(text)
    f = prog.funcs[0x8010CD8]
    assert f.frame == 39952
    assert [(s.kind, s.offset, s.target) for s in f.sites] == [("call", 39952, 0x8010D00)]
    # sub.w sp, r7, #28 restores SP from the frame pointer (r7 = entry - 8): offset 36, then the pops reach 0.
    assert not f.unbounded and not f.notes


def test_direct_call_chain():
    # a holds 8 + 16 at its call, b holds 8 at its call, c's frame is 8 + 40: worst(a) = 24 + 8 + 48 = 80.
    prog = program("""
        08000000 <a>:
         8000000: push {r7, lr}
         8000002: sub sp, #16
         8000004: bl 0x8000010 <b>
         8000008: add sp, #16
         800000a: pop {r7, pc}
        08000010 <b>:
         8000010: push {r7, lr}
         8000012: bl 0x8000020 <c>
         8000016: pop {r7, pc}
        08000020 <c>:
         8000020: push {r4, lr}
         8000022: sub sp, #40
         8000024: add sp, #40
         8000026: pop {r4, pc}
    """)
    a, b, c = (by_name(prog, n).start for n in "abc")
    res = stack.solve(prog, [a], [])
    assert res.worst[c] == 48
    assert res.worst[b] == 8 + 48
    assert res.worst[a] == 24 + 8 + 48 == 80
    assert [n for n, _, _ in res.path[a]] == [a, b, c]
    assert not res.cycles


def test_tail_call_does_not_add_the_callers_frame():
    # a: frame 72, then epilogue and b.w to c (frame 100): the tail call runs at offset 0, so worst(a) = 100,
    # not 172. d's conditional tail call (bne.w) before its push also runs at offset 0; its frame is 8.
    prog = program("""
        08000000 <a>:
         8000000: push {r7, lr}
         8000002: sub sp, #64
         8000004: add sp, #64
         8000006: pop.w {r7, lr}
         800000a: b.w 0x8000020 <c>
        08000020 <c>:
         8000020: push {r4, lr}
         8000022: sub sp, #92
         8000024: add sp, #92
         8000026: pop {r4, pc}
        08000030 <d>:
         8000030: cmp r0, #0
         8000032: bne.w 0x8000020 <c>
         8000036: push {r7, lr}
         8000038: pop {r7, pc}
    """)
    a, c, d = (by_name(prog, n) for n in "acd")
    assert a.frame == 72 and c.frame == 100 and d.frame == 8
    assert [(s.kind, s.offset, s.target) for s in a.sites] == [("tail", 0, c.start)]
    assert [(s.kind, s.offset, s.target) for s in d.sites] == [("tail", 0, c.start)]
    res = stack.solve(prog, [a.start, d.start], [])
    assert res.worst[a.start] == 100
    assert res.worst[d.start] == 100


def test_branch_inside_function_is_not_a_call():
    # A backward loop branch and a forward cbz stay inside the function: no call sites.
    prog = program("""
        08000000 <loop>:
         8000000: push {r7, lr}
         8000002: subs r0, #1
         8000004: bne 0x8000002 <loop+0x2>
         8000006: cbz r1, 0x800000a <loop+0xa>
         8000008: movs r1, #0
         800000a: pop {r7, pc}
    """)
    f = by_name(prog, "loop")
    assert f.sites == [] and f.frame == 8 and not f.notes


def test_recursion_detected_and_allowed_bound():
    # a -> b -> a. Not allowed by default; allowed through "b", the bound enters each function once:
    # a holds 16 at its call, b's frame is 24 (it holds 24 at its call back to a): 16 + 24 = 40.
    src = """
        08000000 <a>:
         8000000: push {r4, r5, r7, lr}
         8000002: bl 0x8000010 <b>
         8000006: pop {r4, r5, r7, pc}
        08000010 <b>:
         8000010: push {r7, lr}
         8000012: sub sp, #16
         8000014: bl 0x8000000 <a>
         8000018: add sp, #16
         800001a: pop {r7, pc}
        08000020 <Reset>:
         8000020: bl 0x8000000 <a>
         8000024: udf #0
    """
    prog = program(src, vector=[0x20001000, 0x8000021], stack=(0x20001000, 0x20000000))
    rep = stack.analyse(prog, [], 75, 8192)
    assert len(rep["cycles"]) == 1
    assert rep["cycles"][0]["functions"] == ["a", "b"]
    assert not rep["cycles"][0]["allowed"]
    assert any("recursion" in e for e in rep["errors"]) and not rep["ok"]

    prog = program(src, vector=[0x20001000, 0x8000021], stack=(0x20001000, 0x20000000))
    rep = stack.analyse(prog, ["b"], 75, 8192)
    assert rep["cycles"][0]["allowed"]
    assert rep["ok"], rep["errors"]
    reset = rep["roots"][0]
    assert reset["worst_bytes"] == 0 + 16 + 24 == 40
    assert [p["function"] for p in reset["path"]] == ["Reset", "a", "b"]

    # A self-recursive function is a cycle too.
    prog = program("""
        08000000 <r>:
         8000000: push {r7, lr}
         8000002: bl 0x8000000 <r>
         8000006: pop {r7, pc}
    """)
    res = stack.solve(prog, [0x8000000], [])
    assert res.cycles and res.cycles[0]["functions"] == ["r"] and not res.cycles[0]["allowed"]


def test_recursion_allowed_only_if_every_cycle_passes_an_allowed_function():
    # Two cycles share "a": a <-> b and a <-> c. Allowing "b" leaves a <-> c: still an error.
    src = """
        08000000 <a>:
         8000000: push {r7, lr}
         8000002: bl 0x8000010 <b>
         8000006: bl 0x8000020 <c>
         800000a: pop {r7, pc}
        08000010 <b>:
         8000010: push {r7, lr}
         8000012: bl 0x8000000 <a>
         8000016: pop {r7, pc}
        08000020 <c>:
         8000020: push {r7, lr}
         8000022: bl 0x8000000 <a>
         8000026: pop {r7, pc}
    """
    res = stack.solve(program(src), [0x8000000], ["b"])
    assert len(res.cycles) == 1 and not res.cycles[0]["allowed"]
    assert res.cycles[0]["not_allowed"] == [["a", "c"]]
    res = stack.solve(program(src), [0x8000000], ["a"])
    assert res.cycles[0]["allowed"]


def test_indirect_call_bounded_by_address_taken_functions():
    # caller: blx r3 at offset 16. Address-taken: g (literal word 0x08000021 in caller's pool) and h (movw/movt),
    # not deep (frame 200, never referenced). Bound = max(g 40, h 8) = 40; worst(caller) = 16 + 40 = 56.
    prog = program("""
        08000000 <caller>:
         8000000: push {r4, r5, r7, lr}
         8000002: ldr r3, [pc, #8]
         8000004: movw r2, #49
         8000008: movt r2, #2048
         800000c: blx r3
         800000e: pop {r4, r5, r7, pc}
        08000010 <$d>:
         8000010: .word 0x08000021
        08000020 <g>:
         8000020: push {r7, lr}
         8000022: sub sp, #32
         8000024: add sp, #32
         8000026: pop {r7, pc}
        08000030 <h>:
         8000030: push {r7, lr}
         8000032: pop {r7, pc}
        08000040 <deep>:
         8000040: push {r7, lr}
         8000042: sub sp, #192
         8000044: add sp, #192
         8000046: pop {r7, pc}
    """)
    caller, g, h, deep = (by_name(prog, n) for n in ("caller", "g", "h", "deep"))
    assert prog.address_taken == {g.start, h.start}
    assert [(s.kind, s.offset) for s in caller.sites] == [("indirect", 16)]
    res = stack.solve(prog, [caller.start], [])
    assert res.worst[stack.INDIRECT] == 40
    assert [(n, k) for n, _, k in res.path[caller.start]] == [(caller.start, None), (g.start, "pointer")]
    assert res.worst[caller.start] == 56
    assert deep.start not in res.worst  # not reached


def test_address_taken_from_data_section_words():
    # A vtable in .rodata (extra_words) takes g's address; the vector table alone does not take isr's.
    prog = program("""
        08000000 <caller>:
         8000000: push {r7, lr}
         8000002: blx r1
         8000004: pop {r7, pc}
        08000010 <g>:
         8000010: push {r4, r5, r6, r7, lr}
         8000012: pop {r4, r5, r6, r7, pc}
        08000020 <isr>:
         8000020: push {r4, r5, r6, r7, lr}
         8000022: sub sp, #400
         8000024: add sp, #400
         8000026: pop {r4, r5, r6, r7, pc}
    """, extra_words=[0x12345678, 0x08000011, 0x08000010], vector=[0x20001000, 0x08000001, 0, 0, 0x08000021])
    assert prog.address_taken == {0x8000010}  # 0x08000010 without the Thumb bit is not a function pointer
    res = stack.solve(prog, [0x8000000], [])
    assert res.worst[0x8000000] == 8 + 20


def test_executor_indirect_call_resolved_to_task_polls():
    # The executor's blx goes to the tasks (class a), the other blx to address-taken functions without the tasks.
    ex = "_ZN16embassy_executor8platform6thread8Executor3run17h0123456789abcdefE"
    t1 = "_ZN16embassy_executor3raw20TaskStorage$LT$F$GT$4poll17h1111111111111111E"
    t2 = "_ZN16embassy_executor3raw20TaskStorage$LT$F$GT$4poll17h2222222222222222E"
    prog = program(f"""
        08000000 <{ex}>:
         8000000: push {{r7, lr}}
         8000002: sub sp, #8
         8000004: ldr r1, [r0, #36]
         8000006: blx r1
         8000008: b 0x8000004 <x>
        08000010 <{t1}>:
         8000010: push {{r7, lr}}
         8000012: sub.w sp, sp, #1000
         8000016: blx r2
         8000018: add.w sp, sp, #1000
         800001c: pop {{r7, pc}}
        08000020 <{t2}>:
         8000020: push {{r7, lr}}
         8000022: movw r0, #17
         8000026: movt r0, #2048
         800002a: movw r0, #33
         800002e: movt r0, #2048
         8000032: pop {{r7, pc}}
        08000040 <fmt>:
         8000040: push {{r7, lr}}
         8000042: sub sp, #24
         8000044: add sp, #24
         8000046: pop {{r7, pc}}
        08000050 <user>:
         8000050: movw r0, #65
         8000054: movt r0, #2048
         8000058: bx lr
    """, dwarf_names={t1: "poll<firmware::__fpga_link_task::__fpga_link_task_inner_function::{async_fn_env#0}>",
                      t2: "poll<firmware::____embassy_main_task::____embassy_main_task_inner_function::{async_fn_env#0}>"})
    assert sorted(prog.task_names.values()) == ["embassy_main", "fpga_link"]
    assert prog.address_taken == {0x8000010, 0x8000020, 0x8000040}
    res = stack.solve(prog, [0x8000000], [])
    assert res.executor_funcs == [0x8000000]
    assert sorted(res.task_targets) == [0x8000010, 0x8000020]
    assert res.indirect_targets == [0x8000040]  # the task polls are left to the executor's class
    # task 1: 1008 held at its blx + fmt 32 = 1040; executor: 16 + 1040 = 1056.
    assert res.worst[0x8000010] == 1008 + 32
    assert res.worst[0x8000000] == 16 + 1040
    assert not res.cycles


def test_dynamic_sp_adjustment_flagged():
    # sub sp, r0 (unknown r0) is unbounded; a root reaching it fails. A constant in the register is fine, and so
    # is the SP restored from r7.
    src = """
        08000000 <alloca>:
         8000000: push {r7, lr}
         8000002: mov r7, sp
         8000004: sub sp, r0
         8000006: mov sp, r7
         8000008: pop {r7, pc}
        08000010 <fixed>:
         8000010: push {r7, lr}
         8000012: movw r1, #5000
         8000016: sub sp, r1
         8000018: add sp, r1
         800001a: pop {r7, pc}
        08000020 <Reset>:
         8000020: bl 0x8000000 <alloca>
         8000024: bl 0x8000010 <fixed>
         8000028: udf #0
    """
    prog = program(src, vector=[0x20001000, 0x8000021], stack=(0x20004000, 0x20000000))
    alloca, fixed = by_name(prog, "alloca"), by_name(prog, "fixed")
    assert len(alloca.unbounded) == 1 and "sub sp, r0" in alloca.unbounded[0].replace("\t", " ")
    assert fixed.frame == 5008 and not fixed.unbounded
    rep = stack.analyse(prog, [], 75, 8192)
    assert rep["unbounded"] and rep["unbounded"][0]["function"] == "alloca"
    assert any("unbounded frame in alloca" in e for e in rep["errors"]) and not rep["ok"]

    # mov sp from an unknown register too.
    prog = program("""
        08000000 <f>:
         8000000: push {r4, lr}
         8000002: mov sp, r4
         8000004: pop {r4, pc}
    """)
    assert by_name(prog, "f").unbounded


def test_it_block_conditional_epilogue_and_return():
    # itt lo; addlo sp; poplo {.., pc}: a conditional return. The fall-through path keeps the full frame (8 + 28)
    # and still calls x at offset 36.
    prog = program("""
        08000000 <f>:
         8000000: push {r7, lr}
         8000002: sub sp, #28
         8000004: cmp r0, #1
         8000006: itt lo
         8000008: addlo sp, #28
         800000a: poplo {r7, pc}
         800000c: bl 0x8000020 <x>
         8000010: add sp, #28
         8000012: pop {r7, pc}
        08000020 <x>:
         8000020: bx lr
    """)
    f = by_name(prog, "f")
    assert f.frame == 36
    assert [(s.kind, s.offset) for s in f.sites] == [("call", 36)]


def test_jump_table_targets_followed():
    # tbb [pc, r0] at 0x8000004: table base 0x8000008, bytes 01 03 -> cases at 0x800000a and 0x800000e.
    # Case 0 allocates 100 B (frame 108); case 1 calls x at offset 8. Were the table not read, case 1 would be
    # "unreached code" analysed at the deepest offset, 108, and a note would say so.
    prog = program("""
        08000000 <sw>:
         8000000: push {r7, lr}
         8000002: cmp r0, #1
         8000004: tbb [pc, r0]
        08000008 <$d>:
         8000008: .short 0x0301
        0800000a <$t>:
         800000a: sub sp, #100
         800000c: b 0x8000014 <sw+0x14>
         800000e: bl 0x8000020 <x>
         8000012: pop {r7, pc}
         8000014: add sp, #100
         8000016: pop {r7, pc}
        08000020 <x>:
         8000020: bx lr
    """)
    f = by_name(prog, "sw")
    assert f.frame == 108
    assert [(s.kind, s.offset) for s in f.sites] == [("call", 8)]
    assert not f.notes


def test_total_and_thresholds():
    # Priorities not known (no --boot-json): every handler is a level of its own. Thread 40 + TIM2 (24 + 108) +
    # DefaultHandler as IRQ 1 (0 + 108) + HardFault (8 + 108) + NMI, which is DefaultHandler (0 + 108) = 504 B of a
    # 630 B region = 80% > 75%: fails; with --max-percent 85 passes. A frame above --max-frame fails on its own.
    # (Before priorities were modelled: one shared handler level, 40 + 132 + 116 = 288 B of 360 B.)
    src = """
        08000000 <Reset>:
         8000000: push {r7, lr}
         8000002: sub sp, #32
         8000004: b 0x8000004 <Reset+0x4>
        08000010 <TIM2>:
         8000010: push {r4, r5, r6, r7, r8, lr}
         8000014: pop {r4, r5, r6, r7, r8, pc}
        08000020 <HardFault>:
         8000020: push {r7, lr}
         8000022: b 0x8000022 <HardFault+0x2>
        08000030 <DefaultHandler>:
         8000030: b 0x8000030 <DefaultHandler>
    """
    vec = [0x20000276, 0x8000001, 0x8000031, 0x8000021] + [0] * 12 + [0x8000011, 0x8000031]

    def rep(**kw):
        prog = program(src, vector=vec, stack=(0x20000276, 0x20000000))
        return stack.analyse(prog, [], kw.get("pct", 75), kw.get("frame", 8192))

    r = rep()
    assert r["region"]["bytes"] == 630
    assert [lv["bytes"] for lv in r["total"]["levels"]] == [40, 24 + 108, 0 + 108, 8 + 108, 0 + 108]
    assert [lv["short"] for lv in r["total"]["levels"]] == ["thread", "handler", "handler", "HardFault", "NMI"]
    assert not r["total"]["priorities"]["known"]
    assert r["total"]["bytes"] == 504 and r["total"]["percent_of_region"] == 80.0
    assert not r["ok"] and any("80.0%" in e for e in r["errors"])
    assert rep(pct=85)["ok"]
    r = rep(pct=85, frame=32)
    assert not r["ok"] and any("frame of Reset is 40 B" in e for e in r["errors"])
    names = [x["name"] for x in r["roots"]]
    assert names[0].startswith("Reset") and "HardFault" in names and "TIM2 (IRQ 0)" in names
    assert any(n.startswith("DefaultHandler (2 vectors)") for n in names)


# Priority levels and the HardFault stack switch. Vector table: NMI (frame 24), HardFault (moves MSP to the top of
# FAULT_STACK, 0x20000c00, then tail-calls fdir_hard_fault, frame 104), SysTick (8), IRQ 0 TIM2 (24), IRQ 1 USART1
# (16), IRQ 2 USART2 (40), IRQ 3 DefaultHandler (0). Main stack region 0x20000000..0x20000800 (2048 B).
LEVELS_SRC = """
    08000000 <Reset>:
     8000000: push {r7, lr}
     8000002: sub sp, #32
     8000004: b 0x8000004 <Reset+0x4>
    08000010 <SysTick>:
     8000010: push {r7, lr}
     8000012: pop {r7, pc}
    08000020 <TIM2>:
     8000020: push {r4, r5, r6, r7, r8, lr}
     8000024: pop {r4, r5, r6, r7, r8, pc}
    08000030 <USART1>:
     8000030: push {r4, r5, r6, lr}
     8000032: pop {r4, r5, r6, pc}
    08000040 <USART2>:
     8000040: push {r7, lr}
     8000042: sub sp, #32
     8000044: add sp, #32
     8000046: pop {r7, pc}
    08000050 <HardFault>:
     8000050: mrs r0, msp
     8000054: mrs r1, psp
     8000058: mov r2, lr
     800005a: ldr r3, [pc, #8]
     800005c: msr msp, r3
     8000060: b.w 0x8000070 <fdir_hard_fault>
    08000064 <$d>:
     8000064: .word 0x20000c00
    08000070 <fdir_hard_fault>:
     8000070: push {r7, lr}
     8000072: sub sp, #96
     8000074: b 0x8000074 <fdir_hard_fault+0x4>
    08000080 <NMI>:
     8000080: push {r4, r5, r6, r7, r8, lr}
     8000084: b 0x8000084 <NMI+0x4>
    08000090 <DefaultHandler>:
     8000090: b 0x8000090 <DefaultHandler>
"""
LEVELS_VEC = ([0x20000800, 0x8000001, 0x8000081, 0x8000051] + [0] * 11
              + [0x8000011, 0x8000021, 0x8000031, 0x8000041, 0x8000091])
FAULT_STACK = [(0x20000800, 0x400, "FAULT_STACK"), (0x20000C00, 0x10, "OTHER")]


def _levels_rep(src=LEVELS_SRC, data_symbols=FAULT_STACK, priorities=None, pct=75):
    prog = program(src, vector=LEVELS_VEC, stack=(0x20000800, 0x20000000), data_symbols=data_symbols)
    return stack.analyse(prog, [], pct, 8192, priorities)


def test_hardfault_stack_switch():
    prog = program(LEVELS_SRC, vector=LEVELS_VEC, stack=(0x20000800, 0x20000000), data_symbols=FAULT_STACK)
    hf = by_name(prog, "HardFault")
    assert hf.stack_switch["address"] == 0x800005C and hf.stack_switch["value"] == 0x20000C00
    assert not hf.unbounded and hf.frame == 0
    r = _levels_rep()
    assert r["ok"], r["errors"]
    # The handler runs on FAULT_STACK (1024 B at 0x20000800, top 0x20000c00 = the literal): HardFault's path is
    # the tail call to fdir_hard_fault, 104 B; an NMI preempts it there: 24 + 108. 236 B = 23.0% of 1024 B.
    (st,) = r["total"]["separate_stacks"]
    assert (st["root"], st["symbol"], st["bytes"], st["top"]) == ("HardFault", "FAULT_STACK", 1024, "0x20000c00")
    assert (st["handler_bytes"], st["nmi_bytes"], st["worst_bytes"], st["percent"]) == (104, 132, 236, 23.0)
    # On the MSP only the HardFault's hardware frame remains.
    hfl = [lv for lv in r["total"]["levels"] if lv["function"] == "HardFault"]
    assert [(lv["bytes"], lv["handler_bytes"], lv["stack"]) for lv in hfl] == [(108, 0, "FAULT_STACK")]
    text = stack.text_report({"elf": "x", "sha256": "", **r}, "x")
    assert "HardFault stack (FAULT_STACK)" in text and "236" in text and "limit 75% = 768 B" in text

    # The same handler on a 256 B stack (same top): 236 B = 92.2% > 75%: fails, on its own line.
    r = _levels_rep(data_symbols=[(0x20000B00, 0x100, "FAULT_STACK")])
    assert not r["ok"]
    assert any("HardFault stack FAULT_STACK: worst case 236 B is 92.2% of its 256 B" in e for e in r["errors"])

    def fails(src=LEVELS_SRC, data_symbols=FAULT_STACK, why="stack pointer switched (msp)"):
        r = _levels_rep(src, data_symbols)
        assert not r["ok"] and not r["total"]["separate_stacks"]
        assert any(e.startswith("unbounded frame in HardFault") and why in e for e in r["errors"]), r["errors"]

    # A store before the switch would run on the old (maybe overflowed) stack: not a switch, unbounded.
    fails(LEVELS_SRC.replace("mov r2, lr", "str r2, [r1]"))
    # A switch to an address that is no data symbol's top, or to a stack inside the main region.
    fails(LEVELS_SRC.replace(".word 0x20000c00", ".word 0x30000000"), why="not the top of")
    fails(data_symbols=[(0x20000400, 0x800, "X")], why="overlaps the main stack region")
    # The switching function also called from thread code.
    fails(LEVELS_SRC.replace("8000004: b 0x8000004 <Reset+0x4>",
                             "8000004: bl 0x8000050 <HardFault>\n 8000008: b 0x8000008 <Reset+0x8>"),
          why="also called")
    # msr psp, or msr msp anywhere else, stays unbounded.
    prog = program("""
        08000000 <f>:
         8000000: movw r0, #0
         8000004: movt r0, #8192
         8000008: msr psp, r0
         800000c: bx lr
        08000010 <g>:
         8000010: push {r7, lr}
         8000012: movw r0, #0
         8000016: msr msp, r0
         800001a: pop {r7, pc}
    """)
    assert by_name(prog, "f").unbounded and by_name(prog, "g").unbounded
    assert by_name(prog, "f").stack_switch is None and by_name(prog, "g").stack_switch is None


def test_priority_levels():
    # Priorities as boot.py leaves them: TIM2 0x40, USART1 0x20, USART2 0x45 (preemption level 4, with TIM2); IRQ 3
    # (DefaultHandler) not enabled: priority 0, the reset value; SysTick not in the JSON: a level of its own.
    # Thread 40 + SysTick (8 + 108) + level 0 (DefaultHandler 0 + 108) + level 2 (USART1 16 + 108) + level 4
    # (max(TIM2 24, USART2 40) + 108) + HardFault entry 108 + NMI (24 + 108) = 776 B of 2048 B = 37.9%.
    pri = {"source": "boot.json", "irq": {0: {"priority": 0x40, "handler": "TIM2"},
                                          1: {"priority": 0x20, "handler": "USART1"},
                                          2: {"priority": 0x45, "handler": "USART2"}}, "system": {}}
    r = _levels_rep(priorities=pri)
    assert r["ok"], r["errors"]
    lv = r["total"]["levels"]
    assert [x["short"] for x in lv] == ["thread", "SysTick", "level 0", "level 2", "level 4", "HardFault entry", "NMI"]
    assert [x["bytes"] for x in lv] == [40, 116, 108, 124, 148, 108, 132]
    assert [x.get("function") for x in lv][2:5] == ["DefaultHandler", "USART1", "USART2"]
    assert lv[4]["handlers"] == ["TIM2", "USART2"] and lv[4]["priority"] == [0x40, 0x45]
    assert r["total"]["bytes"] == 776 and r["total"]["percent_of_region"] == 37.9
    assert r["total"]["priorities"]["known"]

    # SysTick's priority known (0x20): it shares level 2 with USART1 (max(8, 16) = 16): 776 - 116 = 660.
    r = _levels_rep(priorities={**pri, "system": {15: 0x20}})
    assert [x["bytes"] for x in r["total"]["levels"]] == [40, 108, 124, 148, 108, 132]
    assert r["total"]["bytes"] == 660

    # Priorities not known: every handler a level: 40 + SysTick 116 + TIM2 132 + USART1 124 + USART2 148
    # + DefaultHandler 108 + HardFault entry 108 + NMI 132 = 908.
    r = _levels_rep()
    assert [x["bytes"] for x in r["total"]["levels"]] == [40, 116, 132, 124, 148, 108, 108, 132]
    assert r["total"]["bytes"] == 908
    text = stack.text_report({"elf": "x", "sha256": "", **r}, "x")
    assert "priorities NOT KNOWN" in text


def test_load_boot_priorities():
    import json
    import tempfile

    doc = {"run": {"sha256": "ab" * 32},
           "figures": {"nvic_enabled": [
               {"irq": 37, "name": "USART1", "priority": 32, "handler": "USART1", "default_handler": False},
               {"irq": 50, "name": "TIM5", "priority": 48, "handler": "TIM5", "default_handler": False}]}}
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "boot.json")
        with open(path, "w") as fh:
            json.dump(doc, fh)
        p = stack.load_boot_priorities(path)
        assert p["irq"] == {37: {"priority": 32, "handler": "USART1"}, 50: {"priority": 48, "handler": "TIM5"}}
        assert p["system"] == {} and p["elf_sha256"] == "ab" * 32
        doc["figures"]["system_priorities"] = {"SysTick": 16}
        with open(path, "w") as fh:
            json.dump(doc, fh)
        assert stack.load_boot_priorities(path)["system"] == {15: 16}
        with open(path, "w") as fh:
            json.dump({"figures": {}}, fh)
        try:
            stack.load_boot_priorities(path)
            raise AssertionError("a JSON without nvic_enabled was accepted")
        except SystemExit as e:
            assert "nvic_enabled" in str(e)


def test_demangle_and_task_label():
    m = "_ZN16embassy_executor3raw20TaskStorage$LT$F$GT$4poll17hb9ffa0981487723eE"
    assert stack._legacy_rust_demangle(m) == "embassy_executor::raw::TaskStorage<F>::poll"
    # Symbols from the firmware ELF.
    m = "_ZN4core3ptr83drop_in_place$LT$embassy_stm32..usart..UartTx$LT$embassy_stm32..mode..Async$GT$$GT$17h31e203333c6e7c52E"
    assert stack._legacy_rust_demangle(m) == "core::ptr::drop_in_place<embassy_stm32::usart::UartTx<embassy_stm32::mode::Async>>"
    m = ("_ZN111_$LT$$RF$mut$u20$postcard..ser..serializer..Serializer$LT$F$GT$$u20$as$u20$serde_core..ser.."
         "SerializeStruct$GT$15serialize_field17h43aa9e0f4f151097E")
    assert stack._legacy_rust_demangle(m) == (
        "<&mut postcard::ser::serializer::Serializer<F> as serde_core::ser::SerializeStruct>::serialize_field")
    assert stack._legacy_rust_demangle("Reset") is None
    assert stack.task_label("poll<firmware::__bus_rx_task::__bus_rx_task_inner_function::{async_fn_env#0}>", "") == "bus_rx"
    assert stack.task_label(None, "embassy_executor::raw::TaskStorage<app::blinky::{async_fn_env#0}>::poll") == "app::blinky"


def _run_all() -> int:
    tests = [(n, f) for n, f in sorted(globals().items()) if n.startswith("test_") and callable(f)]
    failed = 0
    for name, fn in tests:
        try:
            fn()
            print(f"ok   {name}")
        except Exception as e:  # noqa: BLE001
            failed += 1
            print(f"FAIL {name}: {type(e).__name__}: {e}")
    print(f"{len(tests) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(_run_all())
