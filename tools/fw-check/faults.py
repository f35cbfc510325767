#!/usr/bin/env python3
"""Fault-injection scenarios on the real ELF (emu.Sim), each asserting what the next boot reports.

    python3 tools/fw-check/scenarios.py faults INJECT_ELF --flight FLIGHT_ELF [--only NAME] [--json out.json]

The fault-injection build (`cargo fw-inject`) exports `FDIR_INJECT` ([u32; 2] in no-init RAM): the emulator writes
[0x1A7E_C7ED, kind] there before a boot; about 1 s after boot the firmware stops the way `kind` says
(firmware/src/inject.rs). Scenarios without injection (the crystal, line noise) run on the flight build.
What the firmware reports is read from its USART2 output with `ground decode` (per boot: the byte stream is cut
at each reset), never decoded here: `Housekeeping` (boot_count, safe_mode, clock_source, link_rx_errors) and
`Resets` (the reset history, newest first).
"""

from __future__ import annotations

import json
import os
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import boot  # noqa: E402
import emu  # noqa: E402
import scenarios as sc  # noqa: E402

INJECT_KEY = 0x1A7E_C7ED
INJECT_SYMBOL = "FDIR_INJECT"
IWDG_TIMEOUT_S = 8.0  # docs/firmware.md: 8 s at 32 kHz nominal
FEED_PERIOD_S = 0.25  # the watchdog task's period
# firmware/src/app/mod.rs DEADLINES_MS, read from the source (TaskId order: Link, FpgaCtrl, BusRx, BusTx, Storage,
# Watchdog, Housekeeping, Pps)
def _deadlines() -> dict:
    import re
    src = (Path(__file__).resolve().parents[2] / "firmware/src/app/mod.rs").read_text()
    ms = re.search(r"pub const DEADLINES_MS: \[u32; TASKS\] = \[([^\]]*)\]", src).group(1)
    names = ["Link", "FpgaCtrl", "BusRx", "BusTx", "Storage", "Watchdog", "Housekeeping", "Pps"]
    return {n: int(v.replace("_", "")) / 1000 for n, v in zip(names, ms.split(","), strict=True)}


DEADLINE_S = _deadlines()
PING = 0  # Command::Ping


def inject_address(img) -> int | None:
    return img.addr_of.get(INJECT_SYMBOL)


def injection_symbols(img) -> list:
    """Symbols of the injection code in an ELF (the flight build must have none)."""
    names = [n for n in img.addr_of if n == INJECT_SYMBOL or "inject" in n.lower()]
    return sorted(n for n in names if not n.startswith("{"))  # defmt strings are not code


class Run:
    """One scenario's emulation: a Sim, the bus output cut per boot, decoded with ground."""

    lsi_hz = 32_000.0
    dma_restart = "f4"  # what a DMA stream does when re-enabled after a mid-transfer disable (see emu.Dma)

    def __init__(self, elf, ground, work, img=None, inject=None, inject_boots=1, **kw):
        self.img = img or boot.Image(elf)
        kw.setdefault("lsi_hz", Run.lsi_hz)
        self.m = m = sc.new_sim(elf, img=self.img, **kw)
        self.ground, self.work = ground, work
        self.offsets = [0]
        self.inject, self.inject_left = inject, inject_boots
        addr = inject_address(self.img)
        if inject is not None and addr is None:
            raise sc.ScenarioError(f"{elf}: no {INJECT_SYMBOL} symbol (not a fault-injection build)")
        self.addr = addr
        m.dma_resume_in_place = Run.dma_restart in ("resume-in-place", "resume-no-tcif")
        m.dma_no_tcif_on_disable = Run.dma_restart == "resume-no-tcif"
        self._arm()
        real_reset = m.do_reset

        def do_reset(cause, why):
            self.offsets.append(len(m.bus_tx))
            ok = real_reset(cause, why)
            self._arm()
            return ok
        m.do_reset = do_reset

    def _arm(self):
        if self.inject is not None and self.inject_left > 0:
            self.m.uc.mem_write(self.addr, (INJECT_KEY | (self.inject << 32)).to_bytes(8, "little"))
            self.inject_left -= 1

    def run(self, t, **kw):
        return self.m.run_until(t, **kw)

    def boots(self) -> list:
        """Per boot: the decoded messages it sent."""
        out, bus = [], bytes(self.m.bus_tx)
        edges = self.offsets + [len(bus)]
        for i in range(len(edges) - 1):
            seg = bus[edges[i]:edges[i + 1]]
            out.append(sc.decode(self.ground, seg, self.work, f"boot{i}") if seg else [])
        return out


def last(msgs, kind):
    x = sc.of_kind(msgs, kind)
    return x[-1] if x else None


def cause_name(c) -> str:
    return c if isinstance(c, str) else next(iter(c))


def newest_record(msgs):
    r = last(msgs, "Resets")
    if not r:
        return None
    recs = [x for x in r.get("records", []) if x]
    return recs[0] if recs else None


class Check:
    def __init__(self, name):
        self.name, self.items, self.info = name, [], {}

    def that(self, what, ok, measured):
        self.items.append({"check": what, "ok": bool(ok), "measured": measured})
        return bool(ok)

    @property
    def ok(self):
        return bool(self.items) and all(i["ok"] for i in self.items)


def run_check(name, fn, ctx, host_key="host_s") -> Check:
    """fn(ctx) timed on the host (into c.info[host_key]); a ScenarioError becomes a Check with a failed "ran"."""
    t0 = time.monotonic()
    try:
        c = fn(ctx)
    except sc.ScenarioError as e:
        c = Check(name)
        c.that("ran", False, str(e))
    c.info[host_key] = round(time.monotonic() - t0, 2)
    return c


# -- scenarios ------------------------------------------------------------------------------------------------

def s_hse_dead(ctx) -> Check:
    c = Check("crystal dead at power-on -> HSI, reported")
    r = Run(ctx["flight"], ctx["ground"], ctx["work"], img=ctx["flight_img"], hse_starts=False, max_resets=2)
    r.run(2.3, timeout_s=60)
    m = r.m
    t = m.tree()
    c.that("no reset", len(m.boots) == 1, [b["cause"] for b in m.boots])
    c.that("SYSCLK from the PLL on the HSI", t["sysclk_source"] == "PLL" and t["pll_source"] == "HSI",
           f"{t['sysclk_source']} from {t['pll_source']}, {t['sysclk'] / 1e6:g} MHz")
    hk = last(r.boots()[0], "Housekeeping")
    c.that("Housekeeping clock_source Hsi", hk and hk.get("clock_source") == "Hsi",
           hk and {"clock_source": hk.get("clock_source"), "hsi_trim": hk.get("hsi_trim")})
    return c


def s_css(ctx) -> Check:
    c = Check("crystal fails after boot -> CSS -> NMI -> record -> reset -> HSI")
    r = Run(ctx["flight"], ctx["ground"], ctx["work"], img=ctx["flight_img"], max_resets=2)
    r.m.fail_hse_at(1.5)
    r.run(4.0, timeout_s=60)
    m = r.m
    boots = r.boots()
    c.that("CSS on before the failure (RCC_CR.CSSON)", any(e["kind"] == "css" for e in m.events),
           [e["text"] for e in m.events if e["kind"] in ("css", "hse_fail")])
    c.that("NMI taken", m.exc_counts[emu.NMI] >= 1, m.exc_counts[emu.NMI])
    c.that("one reset, software (the NMI handler's)", [b["cause"] for b in m.boots[1:]] == ["software"],
           [b["cause"] for b in m.boots])
    if len(boots) > 1:
        hk = last(boots[1], "Housekeeping")
        rec = newest_record(boots[1])
        c.that("next boot on the HSI, said in Housekeeping", hk and hk.get("clock_source") in ("Hsi", "HsiAfterClockFailure"),
               hk and hk.get("clock_source"))
        c.that("reset history: ClockFailure", rec and cause_name(rec["cause"]) == "ClockFailure", rec)
    else:
        c.that("a second boot", False, "no reset")
    return c


def record_pc(rec):
    c = rec and rec.get("cause")
    if isinstance(c, dict):
        v = next(iter(c.values()))
        if isinstance(v, dict):
            return v.get("pc")
    return None


def hf(rec):
    c = rec and rec.get("cause")
    return c.get("HardFault", {}) if isinstance(c, dict) else {}


def bad_address_detail(rec):
    h = hf(rec)
    return ("HardFault record: BFAR 0x3000_0000, CFSR PRECISERR|BFARVALID, HFSR FORCED",
            h.get("fault_addr") == 0x3000_0000 and h.get("cfsr", 0) & (emu.PRECISERR | emu.BFARVALID)
            == emu.PRECISERR | emu.BFARVALID and h.get("hfsr", 0) & emu.HFSR_FORCED,
            {k: hex(v) for k, v in h.items()})


def overflow_detail(rec):
    h = hf(rec)
    return ("HardFault record: CFSR STKERR (the frame could not be pushed), fault address just below SRAM",
            h.get("cfsr", 0) & emu.STKERR and 0x1FFF_0000 <= h.get("fault_addr", 0) < 0x2000_0000,
            {k: hex(v) for k, v in h.items()})


def injected(kind, name, want_cause, via_iwdg=False, task=None, pc_in=None, detail=None):
    def run(ctx) -> Check:
        c = Check(name)
        if ctx["inject"] is None:
            c.info["skipped"] = ctx["inject_missing"]
            return c
        t_run = 1.0 + (IWDG_TIMEOUT_S * 32_000.0 / Run.lsi_hz + DEADLINE_S.get(task, 0.0) + 0.5
                       if via_iwdg else 0.5) + 1.8
        r = Run(ctx["inject"], ctx["ground"], ctx["work"], img=ctx["inject_img"], inject=kind, max_resets=2)
        r.run(t_run, timeout_s=90)
        m = r.m
        causes = [b["cause"] for b in m.boots[1:]]
        c.info["events"] = [e["text"] for e in m.events if e["kind"] in ("reset", "lockup", "spin", "handler")][:12]
        c.that("exactly one reset", len(causes) == 1, causes)
        t_inj = next((e["t_us"] / 1e6 for e in m.log if "fault injection" in e["text"]), None)
        c.info["injected_at_s"] = t_inj
        c.info["reset_at_s"] = round(m.boots[1]["t"], 4) if len(m.boots) > 1 else None
        if via_iwdg:
            c.that("reset by the IWDG", causes[:1] == ["iwdg"], causes)
            t_reset = m.boots[1]["t"] if len(m.boots) > 1 else None
            # a hung task is late after its deadline; a spinning one stops the feeder at once
            iwdg = IWDG_TIMEOUT_S * 32_000.0 / Run.lsi_hz
            limit = (t_inj or 1.1) + DEADLINE_S.get(task, 0.0) + FEED_PERIOD_S + iwdg + 0.1
            c.that(f"IWDG within the documented time (injection + {DEADLINE_S.get(task, 0.0):g} s deadline + "
                   f"{FEED_PERIOD_S:g} s feed period + {iwdg:g} s IWDG at LSI {Run.lsi_hz / 1e3:g} kHz, "
                   f"≤ {limit:.2f} s)",
                   t_reset is not None and t_reset <= limit,
                   {"injected_at_s": t_inj and round(t_inj, 3), "reset_at_s": t_reset and round(t_reset, 3)})
        boots = r.boots()
        if len(boots) > 1:
            rec = newest_record(boots[1])
            hk = last(boots[1], "Housekeeping")
            c.that(f"reset history names {want_cause}", rec and cause_name(rec["cause"]) == want_cause, rec)
            if task:
                got = rec and isinstance(rec["cause"], dict) and rec["cause"].get(want_cause, {}).get("task")
                c.that(f"the task named: {task}", got == task, got)
            c.that("Housekeeping after the reset (boot_count 2)", hk and hk.get("boot_count") == 2,
                   hk and {k: hk.get(k) for k in ("boot_count", "safe_mode", "reset_flags")})
            c.info["record"] = rec
            pc = record_pc(rec)
            if pc:
                c.info["record_pc"] = r.img.where(pc)
            if detail:
                c.that(*detail(rec))
            if pc_in:
                c.that(f"the recorded PC is in {pc_in}", pc and pc_in in r.img.where(pc),
                       pc and r.img.where(pc))
        return c
    return run


def s_safe_mode(ctx) -> Check:
    c = Check("3 short runs -> safe mode, bus still answering")
    if ctx["inject"] is None:
        c.info["skipped"] = ctx["inject_missing"]
        return c
    r = Run(ctx["inject"], ctx["ground"], ctx["work"], img=ctx["inject_img"], inject=2, inject_boots=3,
            max_resets=4)
    r.run(3 * 1.3, timeout_s=90, until=lambda: len(r.m.boots) >= 4)
    m = r.m
    t4 = m.now()
    c.that("three resets (panics)", len(m.boots) == 4, [b["cause"] for b in m.boots])
    versions = sc.bus_versions(m)
    version = max(versions) if versions else 4
    ping = sc.command_frame(bytes([version]) + sc.varint(77) + sc.varint(PING))
    sc.send_bus(m, ping, t4 + 1.5)
    r.run(t4 + 2.6, timeout_s=60)
    boots = r.boots()
    if len(boots) >= 4:
        hk = last(boots[3], "Housekeeping")
        res = last(boots[3], "Resets")
        acks = sc.of_kind(boots[3], "Ack")
        c.that("Housekeeping safe_mode true", hk and hk.get("safe_mode") is True,
               hk and {k: hk.get(k) for k in ("boot_count", "safe_mode")})
        c.that("reset history: safe mode, 3 short runs", res and res.get("safe_mode") is True,
               res and {k: res.get(k) for k in ("short_runs", "safe_mode", "boot_count")})
        c.that("the bus answers (Ping acknowledged)", any(a.get("tag") == 77 for a in acks), acks[:3])
        c.that("no Fused while in safe mode (no FPGA tasks)", not sc.of_kind(boots[3], "Fused"),
               sc.count_kinds(boots[3]))
    return c


def s_line_noise(ctx) -> Check:
    """10 s of framing errors on every USART1 byte between clean frames: no reset, line errors counted, Fused
    bit-exact again after (against ground replay of the same byte stream: the garbage holds no valid frame)."""
    c = Check(f"{ctx.get('noise_s') or 10:g} s of framing errors on USART1 -> no reset, counted, Fused bit-exact after")
    secs = ctx.get("noise_s") or 10.0
    pre, post = 330, 1000
    frames = boot.synth_frames(pre + int(secs * sc.FRAME_HZ) + post) if ctx.get("frames") is None else ctx["frames"]
    n = len(frames) // sc.FRAME_LEN
    n_noise = int(secs * sc.FRAME_HZ)
    post = n - pre - n_noise
    rng = random.Random(39)
    stream = bytearray(frames)
    for i in range(pre, pre + n_noise):  # the FPGA keeps sending; the line garbles every byte
        stream[i * sc.FRAME_LEN:(i + 1) * sc.FRAME_LEN] = bytes(rng.getrandbits(8) for _ in range(sc.FRAME_LEN))
    stream = bytes(stream)

    burst = max(1, int(ctx.get("noise_burst") or 4))

    def noise(i, t, data):
        """In the noise, the garbled bytes of `burst` frame periods arrive as one burst (each byte with FE): the
        firmware sees an error per burst, at most FRAME_HZ / burst a second."""
        if not pre <= i < pre + n_noise:
            return data, 0
        k = i - pre
        if k % burst:
            return b"", 0
        return stream[i * sc.FRAME_LEN:(pre + min(k + burst, n_noise)) * sc.FRAME_LEN], emu.FE
    r = Run(ctx["flight"], ctx["ground"], ctx["work"], img=ctx["flight_img"], max_resets=1)
    m = r.m
    r.run(0.2, timeout_s=60)
    t0 = m.now()
    t_end = sc.feed_frames(m, stream, t0, noise=noise)
    r.run(t_end + 0.3, timeout_s=150)
    c.info["frames"] = {"before": pre, "noise": n_noise, "after": post, "noise_burst_frames": burst}
    c.that("no reset", len(m.boots) == 1, [b["cause"] for b in m.boots])
    u1 = m.block("USART1")
    boots = r.boots()
    hks = sc.of_kind(boots[0], "Housekeeping")
    line = [h.get("link_rx_errors", {}).get("line") for h in hks]
    c.that("link line-error counter rises in Housekeeping", len(line) >= 2 and line[-1] and line[-1] > line[0],
           line)
    # reference: the same bytes through ground replay
    path = os.path.join(ctx["work"], "noise.bin")
    with open(path, "wb") as f:
        f.write(stream)
    sc.run_ground(ctx["ground"], "replay", path, "--out", os.path.join(ctx["work"], "noise.kiss"))
    with open(os.path.join(ctx["work"], "noise.kiss"), "rb") as f:
        ref = sc.decode(ctx["ground"], f.read(), ctx["work"], "noise-replay")
    fw_fused, ref_fused = sc.of_kind(boots[0], "Fused"), sc.of_kind(ref, "Fused")
    # the reports of frames after the noise (by frame time), and after one ring's worth of frames (8 KiB = 34
    # frames) for the driver's restart to settle: each must be in the firmware's output, bit for bit
    cmp = {"firmware_fused": len(fw_fused), "replay_fused": len(ref_fused)}
    if len(ref_fused) >= 2:
        dt = (ref_fused[1]["t_us"] - ref_fused[0]["t_us"]) / max(ref_fused[0].get("frames", 32), 1)
        t_clean = (pre + n_noise + 34) * dt
        after = [f for f in ref_fused if f["t_us"] >= t_clean]
        fw_by_t = {}
        for f in fw_fused:
            fw_by_t.setdefault(f["t_us"], []).append(f)
        missing = [f["t_us"] for f in after if f["t_us"] not in fw_by_t]
        differ = [f["t_us"] for f in after if f["t_us"] in fw_by_t and fw_by_t[f["t_us"]] != [f]]
        dup_or_extra = sorted(t for t, v in fw_by_t.items() if t >= t_clean and (len(v) > 1 or
                                                                                 t not in {f["t_us"] for f in after}))
        cmp.update(compared=len(after), missing=len(missing), differing=len(differ), extra=len(dup_or_extra),
                   first_missing_t_us=missing[:1], first_differing_t_us=differ[:1], first_extra_t_us=dup_or_extra[:1])
        if differ:
            t = differ[0]
            cmp["firmware_msg"] = fw_by_t[t][0]
            cmp["replay_msg"] = next(f for f in after if f["t_us"] == t)
        ok = after and not missing and not differ and not dup_or_extra
    else:
        ok = False
    c.that("Fused bit-exact again after the noise (frame time after the noise + one ring of frames)", ok, cmp)
    c.info["firmware_fused_before_noise"] = sum(1 for f in fw_fused if f["t_us"] < pre * 1e6 / sc.FRAME_HZ)
    c.info["usart1_rx_lost_bytes"] = u1.rx_lost
    return c


def s_flight_clean(ctx) -> Check:
    c = Check("flight ELF has no injection code (symbol table)")
    syms = injection_symbols(ctx["flight_img"])
    c.that("no FDIR_INJECT / inject symbols in the flight ELF", not syms, syms[:10])
    if ctx["inject_img"] is not None:
        c.that("the injection build has them", inject_address(ctx["inject_img"]) is not None,
               injection_symbols(ctx["inject_img"])[:5])
    return c


def s_idle_config(ctx) -> Check:
    """The issue's 'done when' on the flight ELF at idle: CSS on, no enabled interrupt vectored to DefaultHandler;
    and priorities set on purpose (not all 0), debug-in-sleep off."""
    c = Check("flight ELF at idle: CSS on, no enabled IRQ on DefaultHandler, priorities set, DBGMCU off")
    r = Run(ctx["flight"], ctx["ground"], ctx["work"], img=ctx["flight_img"], max_resets=0)
    r.run(0.5, timeout_s=60)
    m, img = r.m, ctx["flight_img"]
    cr = m.rcc.regs.get(emu.Rcc.CR, 0)
    c.that("RCC_CR.CSSON", cr & (1 << 19), f"RCC_CR=0x{cr:08x}")
    vec = m.vectors(98)
    default = img.addr_of.get("DefaultHandler")
    enabled = m.ppb.irq_enabled()
    unbound = [boot.IRQ_NAMES.get(n, str(n)) for n in enabled
               if n < 82 and default is not None and vec[16 + n] & ~1 == default & ~1]
    c.that("no enabled interrupt vectored to DefaultHandler", not unbound, unbound)
    prios = {boot.IRQ_NAMES.get(n, str(n)): m.ppb.irq_priority(n) >> 4 for n in enabled}
    c.that("interrupt priorities set (not all 0)", any(prios.values()), prios)
    dbg = m.ppb.regs.get(0x4_2004, 0)
    c.that("DBGMCU_CR debug-in-sleep/stop/standby off", dbg & 7 == 0, f"DBGMCU_CR=0x{dbg:08x}")
    c.that("no reset", len(m.boots) == 1, [b["cause"] for b in m.boots])
    return c


FAULT_SCENARIOS = {
    "idle-config": s_idle_config,
    "flight-symbols": s_flight_clean,
    "hse-dead": s_hse_dead,
    "css": s_css,
    "stack-overflow": injected(1, "stack overflow -> HardFault on its own stack -> record -> reset", "HardFault",
                               detail=overflow_detail),
    "panic": injected(2, "panic -> record -> reset", "Panic"),
    "hung-task": injected(3, "housekeeping task hangs -> IWDG -> record names the task", "Watchdog",
                          via_iwdg=True, task="Housekeeping"),
    "spinning-task": injected(4, "a task spins without yielding -> IWDG -> Watchdog record with its PC",
                              "Watchdog", via_iwdg=True, pc_in="[task inject]"),
    "unbound-irq": injected(5, "an interrupt without a handler -> DefaultHandler record -> reset", "UnhandledIrq"),
    "bad-address": injected(6, "read of an unmapped address -> HardFault record -> reset", "HardFault",
                            pc_in="[task inject]", detail=bad_address_detail),
    "safe-mode": s_safe_mode,
    "line-noise": s_line_noise,
}


def run_all(inject_elf, flight_elf, ground, only=None, verbose=False, noise_s=None, noise_burst=None) -> list:
    work = tempfile.mkdtemp(prefix="faults-")
    try:
        ctx = {"ground": ground, "work": work, "flight": flight_elf or inject_elf,
               "flight_img": boot.Image(flight_elf or inject_elf), "inject": None, "inject_img": None,
               "inject_missing": None, "noise_s": noise_s, "noise_burst": noise_burst}
        if inject_elf and os.path.isfile(inject_elf):
            img = boot.Image(inject_elf)
            if inject_address(img) is not None:
                ctx["inject"], ctx["inject_img"] = inject_elf, img
            else:
                ctx["inject_missing"] = f"{inject_elf} has no {INJECT_SYMBOL} symbol (not a fault-injection build)"
        else:
            ctx["inject_missing"] = f"no fault-injection ELF at {inject_elf}"
        out = []
        for name, fn in FAULT_SCENARIOS.items():
            if only and name not in only:
                continue
            c = run_check(name, fn, ctx)
            out.append((name, c))
            if verbose:
                print_one(name, c)
        return out
    finally:
        shutil.rmtree(work, True)


def print_one(name, c):
    status = "SKIP" if c.info.get("skipped") else ("PASS" if c.ok else "FAIL")
    print(f"  {status}  {name}: {c.name}  ({c.info.get('host_s', '?')} s host)"
          + (f"  [{c.info['skipped']}]" if c.info.get("skipped") else ""))
    for i in c.items:
        print(f"        {'ok ' if i['ok'] else 'BAD'} {i['check']}: {json.dumps(i['measured'], default=str)[:300]}")


def main_faults(a) -> int:
    ground = a.ground or sc.find_ground()
    if ground is None:
        print("scenarios.py faults: no ground binary", file=sys.stderr)
        return 2
    Run.lsi_hz = a.lsi_hz
    Run.dma_restart = a.dma_restart
    res = run_all(a.elf, a.flight, ground, a.only, verbose=a.verbose, noise_s=a.noise_s, noise_burst=a.noise_burst)
    if not a.verbose:
        for name, c in res:
            print_one(name, c)
    failed = [n for n, c in res if not c.ok and not c.info.get("skipped")]
    skipped = [n for n, c in res if c.info.get("skipped")]
    print(f"RESULT: {'PASS' if not failed else 'FAIL'} ({len(res) - len(failed) - len(skipped)} passed, "
          f"{len(failed)} failed, {len(skipped)} skipped)")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({n: {"ok": c.ok, "name": c.name, "checks": c.items, "info": c.info} for n, c in res}, f,
                      indent=1, default=str)
    return 1 if failed else 0
