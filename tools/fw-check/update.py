#!/usr/bin/env python3
"""In-orbit update scenarios on the REAL ELFs (docs/update.md): the bootloader at 0x0800_0000 and the application
at ACTIVE + 0x200 in one emulated F405 (emu.Sim with boot.py's flash model), signed images and the boot state as raw
bytes in flash, run from the reset vector until the application's executor idles.

    python3 tools/fw-check/update.py boot   --bootloader BL_ELF --app APP_ELF [--app-image APP_IMAGE]
    python3 tools/fw-check/update.py swap   --bootloader BL_ELF --app APP_ELF [--app-image APP_IMAGE] \\
                                            --new-app NEW_ELF --image NEW_IMAGE
    python3 tools/fw-check/update.py refuse --bootloader BL_ELF --app APP_ELF [--app-image APP_IMAGE] \\
                                            --new-app NEW_ELF --image NEW_IMAGE [--flip-offset N]
    python3 tools/fw-check/update.py all    ... (the three, with swap's arguments)
    common: [--flash-timing typ|max] [--bsy-polls N] [--lsi-hz HZ] [--virtual-s S] [--timeout S] [--json OUT] [-v]

BL_ELF defaults to target/thumbv7em-none-eabihf/fw/bootloader, APP_ELF to target/thumbv7em-none-eabihf/fw/firmware.
APP_IMAGE is the running application's signed image (`ground fw-sign APP_ELF ...`), written to ACTIVE so that its
header (version) is there as after an update; without it ACTIVE holds the ELF's bytes alone (as flashed with a
probe: the boot report's ACTIVE version is then 0). NEW_IMAGE is `ground fw-sign NEW_ELF --key K --version V --out
NEW_IMAGE` of a second application build NEW_ELF, signed with the private half of the key the bootloader was built
with (FW_UPDATE_PUBKEY). Exit status 0 when every check passed, 1 when one failed, 2 on a usage or tooling error
(a missing or unreadable file, an image that is not NEW_ELF's).

Scenarios
---------
boot    bootloader + application in ACTIVE, boot state erased: the application reaches the executor's idle (every
        task polled), the boot report says Booted (0), no reset.
swap    + NEW_IMAGE in DFU (0x0806_0000) and embassy-boot's swap request in the boot state sector (its first word
        0xF0F0F0F0, "progress valid" and the progress words erased): the bootloader checks the image and swaps;
        afterwards ACTIVE holds the DFU's first 256 KiB byte for byte and DFU holds the old ACTIVE one sector up
        (embassy-boot's swap: ACTIVE page k -> DFU page k + 1, DFU page k -> ACTIVE page k), NEW_ELF is the code
        that runs (identified in flash) and reaches idle, the boot report says Swapped (1) with the new version, the
        IWDG never expired (the bootloader feeds it around each erase: the largest gap between feeds is reported
        against the timeout, and below the timeout at the LSI's fastest, 47 kHz), and no flash-interface violation.
refuse  the same with one payload byte flipped (`--flip-offset`, default the middle of the payload): the bootloader
        refuses (boot report Refused (3) with a non-zero refusal code, ImageError::Hash = 7 expected), ACTIVE is
        byte for byte what it was and APP_ELF boots to idle.
Each reports the erases (sector, start, duration, PSIZE), word programs, the flash time, the bootloader's phase
(virtual time from reset to its VTOR write, host time) and the whole run's host time.

The boot report is read at the bootloader's VTOR write (before the application runs) and again at the end: six
little-endian words at 0x2000_0000 (shared::update::BootReport): magic 0xB007_2E90, action (0 booted, 1 swapped,
2 reverted, 3 refused), refusal code, ACTIVE version, DFU version, !magic.

What the emulation is (and is not): boot.py and emu.py's docstrings; the flash: boot.py "Flash programming and
erase" (erase and program times from DS8626 at --flash-timing, the maximum by default: the IWDG check is then the
worst case; BSY reads `--bsy-polls` times after each operation).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import struct
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import boot  # noqa: E402
import emu  # noqa: E402
import scenarios as sc  # noqa: E402
from faults import Check, run_check  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(HERE))
DEFAULT_BOOTLOADER = os.path.join(ROOT, "target/thumbv7em-none-eabihf/fw/bootloader")
DEFAULT_APP = os.path.join(ROOT, "target/thumbv7em-none-eabihf/fw/firmware")

# docs/update.md: the memory map
STATE, STATE_LEN = 0x0801_0000, 64 << 10
ACTIVE, ACTIVE_LEN = 0x0802_0000, 256 << 10
DFU, DFU_LEN = 0x0806_0000, 384 << 10
PAGE = 128 << 10  # embassy-boot's page: the largest erase size of the partitions
HEADER_LEN = 512
SWAP_MAGIC = b"\xf0" * 4  # embassy-boot's State::Swap (its first state word; the rest erased)
REPORT_ADDR, REPORT_MAGIC = 0x2000_0000, 0xB007_2E90
ACTIONS = ["Booted", "Swapped", "Reverted", "Refused"]
LSI_MAX_HZ = 47_000.0  # DS8626: the LSI (the IWDG's clock) is 17-47 kHz over parts and temperature
REFUSALS = {1: "Magic", 2: "Format", 3: "Board", 4: "Rollback", 5: "TooLarge", 6: "Signature", 7: "Hash", 8: "Flash"}


class UpdateError(Exception):
    """A usage or tooling problem (exit status 2)."""


# -- the image and the report (docs/update.md) ----------------------------------------------------------------

def parse_image(data: bytes) -> dict:
    """The header fields of a signed image, and whether the payload's SHA-512 is the header's."""
    if len(data) < HEADER_LEN or data[:4] != b"IMUF":
        return {"valid": False, "why": "no IMUF header"}
    fmt, hlen, board, version, plen = struct.unpack_from("<HHIII", data, 4)
    payload = data[HEADER_LEN:HEADER_LEN + plen]
    return {"valid": fmt == 1 and hlen == HEADER_LEN and len(payload) == plen, "format": fmt, "header_len": hlen,
            "board_id": board, "version": version, "payload_len": plen, "image_len": len(data),
            "sha512_ok": hashlib.sha512(payload).digest() == data[32:96]}


def parse_report(raw: bytes) -> dict | None:
    """shared::update::BootReport from its six words, or None (no report: magic or check word wrong)."""
    w = struct.unpack("<6I", raw[:24])
    if w[0] != REPORT_MAGIC or w[5] != (~REPORT_MAGIC & 0xFFFF_FFFF) or w[1] > 3 or w[2] > 0xFF:
        return None
    return {"action": w[1], "action_name": ACTIONS[w[1]], "refusal": w[2],
            "refusal_name": REFUSALS.get(w[2], "none" if w[2] == 0 else "?"), "active_version": w[3],
            "dfu_version": w[4]}


def flip_payload_byte(image: bytes, offset: int | None = None) -> tuple[bytes, int]:
    """The image with one payload byte inverted (at `offset` into the payload, default its middle)."""
    h = parse_image(image)
    plen = h.get("payload_len") or (len(image) - HEADER_LEN)
    off = plen // 2 if offset is None else offset
    if not 0 <= off < plen:
        raise UpdateError(f"--flip-offset {off} is outside the payload (0..{plen - 1})")
    b = bytearray(image)
    b[HEADER_LEN + off] ^= 0xFF
    return bytes(b), off


def payload_matches_elf(image: bytes, elf: boot.Image) -> bool:
    """Whether the image's payload is the ELF's flash contents from ACTIVE + 0x200 on."""
    payload = image[HEADER_LEN:]
    for addr, data in elf.flash_segments():
        o = addr - (ACTIVE + HEADER_LEN)
        if o < 0 or payload[o:o + len(data)] != data:
            return False
    return bool(elf.flash_segments())


def read_file(path: str, what: str) -> bytes:
    if not path or not os.path.isfile(path):
        raise UpdateError(f"no {what} at {path}")
    with open(path, "rb") as f:
        return f.read()


def load_elf(path: str, what: str, need_stack: bool = True) -> boot.Image:
    if not path or not os.path.isfile(path):
        raise UpdateError(f"no {what} ELF at {path}")
    try:
        return boot.Image(path, need_stack=need_stack)
    except boot.ToolError as e:
        raise UpdateError(str(e))


# -- one emulated boot ----------------------------------------------------------------------------------------

class Run:
    """bootloader + application (+ images) in one flash, from the reset vector."""

    def __init__(self, bootloader: boot.Image, app: boot.Image, *, new_app: boot.Image | None = None,
                 active_image: bytes | None = None, dfu_image: bytes | None = None, swap: bool = False,
                 lsi_hz: float = 32_000.0, flash_timing: str = "max", bsy_polls: int = 1, verbose: bool = False,
                 max_resets: int = 3):
        blobs = []
        if active_image is not None:
            if not payload_matches_elf(active_image, app):
                raise UpdateError("--app-image: its payload is not the --app ELF's flash contents")
            if len(active_image) > ACTIVE_LEN:
                raise UpdateError(f"--app-image: {len(active_image)} B do not fit ACTIVE ({ACTIVE_LEN} B)")
            blobs.append((ACTIVE, active_image, "ACTIVE image"))
        if dfu_image is not None:
            if len(dfu_image) > DFU_LEN:
                raise UpdateError(f"the DFU image ({len(dfu_image)} B) does not fit DFU ({DFU_LEN} B)")
            blobs.append((DFU, dfu_image, "DFU image"))
        if swap:
            blobs.append((STATE, SWAP_MAGIC, "boot state: swap requested"))
        self.bootloader, self.app, self.new_app = bootloader, app, new_app
        self.images = boot.ImageSet([bootloader, app], candidates=[new_app] if new_app else [], blobs=blobs)
        self.m = m = emu.Sim(self.images, sc.sim_args(verbose=verbose), lsi_hz=lsi_hz, max_resets=max_resets,
                             flash_timing=flash_timing, flash_bsy_polls=bsy_polls)
        self.jumps = []
        real = m.vtor_written

        def vtor_written(vtor):
            self.jumps.append({"vtor": vtor, "t_s": round(m.now(), 6), "host_s": round(time.monotonic() - self.t0, 3),
                               "insn": m.insns, "report": bytes(m.uc.mem_read(REPORT_ADDR, 24)),
                               "iwdg_keys": len(m.block("IWDG").keys)})
            real(vtor)
        m.vtor_written = vtor_written
        self.t0 = time.monotonic()
        m.power_on()
        self.flash0 = bytes(m.flash_mem)
        self.result = None

    def run_to_idle(self, target: boot.Image, t_max: float, timeout_s: float) -> str:
        """Runs until `target`'s code idles at WFE (the executor's first idle) or the run ends."""
        m = self.m

        def done():
            at = getattr(m, "idle_pc", None)
            return at is not None and at in target.wfe and any(im.sha256 == target.sha256 for im in self.images.active)
        self.result = m.run_until(t_max, timeout_s=timeout_s, until=done)
        self.host_s = time.monotonic() - self.t0
        return self.result

    # -- what happened ---------------------------------------------------------------------------------------
    def slot(self, addr: int, n: int, initial: bool = False) -> bytes:
        mem = self.flash0 if initial else self.m.flash_mem
        return bytes(mem[addr - boot.FLASH_BASE:addr - boot.FLASH_BASE + n])

    def report(self) -> dict:
        """The boot report at the bootloader's jump (and at the end, when the application changed it)."""
        first = self.jumps[0]["report"] if self.jumps else None
        end = bytes(self.m.uc.mem_read(REPORT_ADDR, 24))
        out = {"at_jump": parse_report(first) if first else None, "at_end": parse_report(end)}
        out["report"] = out["at_jump"] or out["at_end"]
        return out

    def iwdg(self) -> dict:
        """The watchdog during the bootloader's phase (reset .. its VTOR write): started?, the largest gap between
        feeds (start, reloads, the jump) against the timeout."""
        m = self.m
        iw = m.block("IWDG")
        t_jump = self.jumps[0]["t_s"] if self.jumps else m.now()
        keys = [(k, t) for k, _, t in iw.keys if t <= t_jump + 1e-9]
        start = next((t for k, t in keys if k == 0xCCCC), None)
        out = {"started_by_bootloader": start is not None, "timeout_s": round(iw.timeout_s() * 32_000 / m.lsi_hz, 3),
               "timeout_fastest_lsi_s": round(iw.timeout_s() * 32_000 / LSI_MAX_HZ, 3),
               "lsi_hz": m.lsi_hz, "resets": [b["cause"] for b in m.boots[1:]]}
        if start is not None:
            feeds = [start] + [t for k, t in keys if k == 0xAAAA and t >= start] + [t_jump]
            gaps = [b - a for a, b in zip(feeds, feeds[1:])]
            out.update(feeds=len(feeds) - 2, max_gap_s=round(max(gaps), 4) if gaps else 0.0,
                       margin_s=round(out["timeout_s"] - (max(gaps) if gaps else 0.0), 4))
        return out

    def summary(self) -> dict:
        m = self.m
        fl = m.flash_summary()
        jump = self.jumps[0] if self.jumps else None
        app_polls = {a: n for a, n in self.target_polls().items()}
        return {
            "result": self.result, "stop": m.stop_msg, "virtual_s": round(m.now(), 6),
            "host_s": round(getattr(self, "host_s", time.monotonic() - self.t0), 3),
            "bootloader_phase": None if jump is None else {"virtual_s": jump["t_s"], "host_s": jump["host_s"],
                                                           "instructions": jump["insn"], "vtor": f"0x{jump['vtor']:08x}"},
            "resets": [b["cause"] for b in m.boots[1:]], "code_in_flash": [im.label() for im in self.images.active],
            "flash": {k: v for k, v in fl.items() if k != "violations"} | {"violations": fl["violations"][:10]},
            "tasks_polled": app_polls,
            "warnings": [w["text"] for w in m.warnings[:20]],
            "log": [f"{e['level']} {e['text']}" for e in m.log[:40]],
        }

    def target_polls(self) -> dict:
        """Polls of each task of the application in flash now (the primary ELF)."""
        p = self.images.primary
        return {p.task_polls[a]: self.m.polled[a] for a in p.task_polls}


# -- the scenarios ----------------------------------------------------------------------------------------------

def common_checks(c: Check, r: Run, target: boot.Image):
    m = r.m
    c.that(f"{os.path.basename(target.path)} reaches the executor's idle", r.result == "until",
           f"{r.result}: {m.stop_msg}" if r.result != "until" else f"at {m.now():.3f} s virtual")
    polls = r.target_polls()
    c.that("every task of the application polled", polls and all(polls.values()), polls)
    c.that("no reset (no IWDG expiry, no fault reset)", len(m.boots) == 1, [b["cause"] for b in m.boots[1:]])
    fl = m.flash_summary()
    c.that("no flash-interface violation", fl["violation_count"] == 0,
           [v["text"] for v in fl["violations"][:5]] or "none")
    c.that("no erase cut short", not any(e["cut"] for e in fl["erases"]), [e for e in fl["erases"] if e["cut"]])


def report_check(c: Check, r: Run, action: int, **want):
    rep = r.report()
    got = rep["report"]
    c.info["boot_report"] = rep
    ok = got is not None and got["action"] == action and all(got.get(k) == v for k, v in want.items())
    c.that(f"boot report: {ACTIONS[action]} ({action})" + "".join(f", {k} {v}" for k, v in want.items()), ok,
           got or "no valid report at 0x2000_0000 (magic / check word)")
    return got


def s_boot(ctx) -> Check:
    c = Check("bootloader + application in ACTIVE -> the application boots, report Booted")
    r = Run(ctx["bootloader"], ctx["app"], active_image=ctx.get("app_image"), **ctx["run_kw"])
    r.run_to_idle(ctx["app"], ctx["virtual_s"], ctx["timeout"])
    common_checks(c, r, ctx["app"])
    want = {"refusal": 0}
    if ctx.get("app_image") is not None:
        want["active_version"] = parse_image(ctx["app_image"])["version"]
    report_check(c, r, 0, **want)
    c.that("ACTIVE unchanged", r.slot(ACTIVE, ACTIVE_LEN) == r.slot(ACTIVE, ACTIVE_LEN, initial=True), "")
    c.info.update(r.summary())
    c.info["iwdg"] = r.iwdg()
    return c


def s_swap(ctx) -> Check:
    c = Check("signed image in DFU + swap request -> swapped, the new application boots, report Swapped")
    img = ctx["image"]
    h = parse_image(img)
    r = Run(ctx["bootloader"], ctx["app"], new_app=ctx["new_app"], active_image=ctx.get("app_image"),
            dfu_image=img, swap=True, **ctx["run_kw"])
    old_active, old_dfu = r.slot(ACTIVE, ACTIVE_LEN, initial=True), r.slot(DFU, DFU_LEN, initial=True)
    r.run_to_idle(ctx["new_app"], ctx["virtual_s"], ctx["timeout"])
    common_checks(c, r, ctx["new_app"])
    report_check(c, r, 1, refusal=0, active_version=h.get("version"))
    active, dfu = r.slot(ACTIVE, ACTIVE_LEN), r.slot(DFU, DFU_LEN)
    c.that("ACTIVE holds the DFU's first 256 KiB (the new image, header and payload), byte for byte",
           active == old_dfu[:ACTIVE_LEN], first_difference(active, old_dfu[:ACTIVE_LEN], ACTIVE))
    c.that("DFU holds the old ACTIVE one page up (embassy-boot's swap), byte for byte",
           dfu[PAGE:PAGE + ACTIVE_LEN] == old_active, first_difference(dfu[PAGE:PAGE + ACTIVE_LEN], old_active,
                                                                        DFU + PAGE))
    c.that("the new application's code is what runs", any(im.sha256 == ctx["new_app"].sha256
                                                           for im in r.images.active),
           [im.label() for im in r.images.active])
    iw = r.iwdg()
    c.that("the IWDG never expired during the swap", not iw["resets"],
           {k: iw.get(k) for k in ("started_by_bootloader", "feeds", "max_gap_s", "timeout_s", "margin_s", "resets")})
    c.that("the largest gap between the bootloader's IWDG feeds is below the timeout at the fastest LSI (47 kHz)",
           not iw["started_by_bootloader"] or iw["max_gap_s"] < iw["timeout_fastest_lsi_s"],
           {k: iw.get(k) for k in ("max_gap_s", "timeout_fastest_lsi_s")})
    fl = r.m.flash_summary()
    c.that("the swap erased and programmed (ACTIVE and DFU sectors)",
           {5, 6} <= {s for e in fl["erases"] for s in e["sectors"]} and fl["programs"] > 0,
           {"erases": [e["sectors"] for e in fl["erases"]], "programs": fl["programs"]})
    c.info.update(r.summary())
    c.info["iwdg"] = iw
    c.info["image"] = h
    c.info["state_word_after"] = r.slot(STATE, 8).hex()
    return c


def s_refuse(ctx) -> Check:
    c = Check("the same image with one payload byte flipped -> refused, the old application boots unchanged")
    img, off = flip_payload_byte(ctx["image"], ctx.get("flip_offset"))
    r = Run(ctx["bootloader"], ctx["app"], new_app=ctx["new_app"], active_image=ctx.get("app_image"),
            dfu_image=img, swap=True, **ctx["run_kw"])
    r.run_to_idle(ctx["app"], ctx["virtual_s"], ctx["timeout"])
    common_checks(c, r, ctx["app"])
    got = report_check(c, r, 3)
    c.that("a refusal code (ImageError::code, 1..8; Hash = 7 expected for a flipped payload byte)",
           got is not None and got["refusal"] in REFUSALS, got and f"{got['refusal']} ({got['refusal_name']})")
    c.that("ACTIVE unchanged, byte for byte", r.slot(ACTIVE, ACTIVE_LEN) == r.slot(ACTIVE, ACTIVE_LEN, initial=True),
           first_difference(r.slot(ACTIVE, ACTIVE_LEN), r.slot(ACTIVE, ACTIVE_LEN, initial=True), ACTIVE))
    fl = r.m.flash_summary()
    c.that("no ACTIVE sector erased", not {5, 6} & {s for e in fl["erases"] for s in e["sectors"]},
           [e["sectors"] for e in fl["erases"]])
    c.info.update(r.summary())
    c.info["iwdg"] = r.iwdg()
    c.info["flipped_payload_offset"] = off
    c.info["state_word_after"] = r.slot(STATE, 8).hex()
    return c


def first_difference(a: bytes, b: bytes, base: int):
    if a == b:
        return f"{len(a)} B equal"
    i = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    return f"first difference at 0x{base + i:08x}: {a[i:i + 8].hex()} vs {b[i:i + 8].hex()}"


SCENARIOS = {"boot": s_boot, "swap": s_swap, "refuse": s_refuse}


def run_scenarios(names, ctx, verbose=False) -> list:
    out = []
    for name in names:
        c = run_check(name, SCENARIOS[name], ctx, host_key="scenario_host_s")
        out.append((name, c))
        if verbose:
            print_one(name, c)
    return out


def print_one(name, c):
    print(f"  {'PASS' if c.ok else 'FAIL'}  {name}: {c.name}  ({c.info.get('scenario_host_s', '?')} s host)")
    for i in c.items:
        print(f"        {'ok ' if i['ok'] else 'BAD'} {i['check']}: {json.dumps(i['measured'], default=str)[:300]}")
    fl, bp = c.info.get("flash"), c.info.get("bootloader_phase")
    if fl:
        er = ", ".join(f"{'mass' if e['mass'] else 's' + str(e['sectors'][0])} {e['duration_s']:g} s {e['psize']}"
                       for e in fl["erases"][:12])
        print(f"        flash ({fl['timing']}): {fl['erase_count']} erase(s) {fl['erase_s']:g} s [{er}]; "
              f"{fl['programs']:,} program(s) {fl['program_s']:g} s")
    if bp:
        print(f"        bootloader: {bp['virtual_s']:.3f} s virtual, {bp['host_s']:.2f} s host, "
              f"{bp['instructions']:,} instructions; whole run {c.info.get('virtual_s')} s virtual, "
              f"{c.info.get('host_s')} s host")
    iw = c.info.get("iwdg")
    if iw and iw.get("started_by_bootloader"):
        print(f"        IWDG: {iw['feeds']} feed(s), largest gap {iw['max_gap_s']} s of {iw['timeout_s']} s")


def build_ctx(a, names) -> dict:
    ctx = {"virtual_s": a.virtual_s, "timeout": a.timeout, "flip_offset": a.flip_offset,
           "run_kw": {"lsi_hz": a.lsi_hz, "flash_timing": a.flash_timing, "bsy_polls": a.bsy_polls,
                      "verbose": a.verbose}}
    ctx["bootloader"] = load_elf(a.bootloader, "bootloader", need_stack=False)
    ctx["app"] = load_elf(a.app, "application")
    if a.app_image:
        ctx["app_image"] = read_file(a.app_image, "--app-image")
    if set(names) & {"swap", "refuse"}:
        if not a.new_app or not a.image:
            raise UpdateError("swap and refuse need --new-app NEW_ELF and --image NEW_IMAGE (`ground fw-sign NEW_ELF`)")
        ctx["new_app"] = load_elf(a.new_app, "--new-app")
        ctx["image"] = read_file(a.image, "--image")
        h = parse_image(ctx["image"])
        if not h["valid"]:
            raise UpdateError(f"--image {a.image}: not a signed image ({h.get('why') or h})")
        if not payload_matches_elf(ctx["image"], ctx["new_app"]):
            raise UpdateError(f"--image {a.image}: its payload is not {a.new_app}'s flash contents")
    return ctx


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenario", choices=["boot", "swap", "refuse", "all"])
    ap.add_argument("--bootloader", default=DEFAULT_BOOTLOADER, help=f"bootloader ELF (default {DEFAULT_BOOTLOADER})")
    ap.add_argument("--app", default=DEFAULT_APP, help=f"the running application's ELF (default {DEFAULT_APP})")
    ap.add_argument("--app-image", help="its signed image, written to ACTIVE (default: the ELF's bytes alone)")
    ap.add_argument("--new-app", help="swap/refuse: the second application build's ELF")
    ap.add_argument("--image", help="swap/refuse: its signed image (ground fw-sign), written to DFU")
    ap.add_argument("--flip-offset", type=int, help="refuse: payload byte to invert (default: the middle)")
    ap.add_argument("--flash-timing", choices=["typ", "max"], default="max",
                    help="DS8626 erase/program times (default max: the watchdog's worst case)")
    ap.add_argument("--bsy-polls", type=int, default=1, help="SR reads with BSY after each flash operation (1)")
    ap.add_argument("--lsi-hz", type=float, default=32_000.0, help="the IWDG's clock (32 kHz nominal, 17-47 kHz)")
    ap.add_argument("--virtual-s", type=float, default=90.0, help="virtual-time limit per scenario, s (90)")
    ap.add_argument("--timeout", type=float, default=600.0, help="host-time limit per scenario, s (600)")
    ap.add_argument("--json", help="write every check and figure as JSON")
    ap.add_argument("-v", "--verbose", action="store_true")
    return ap


def main(argv=None) -> int:
    a = parser().parse_args(argv)
    names = list(SCENARIOS) if a.scenario == "all" else [a.scenario]
    try:
        ctx = build_ctx(a, names)
        res = run_scenarios(names, ctx)
    except UpdateError as e:
        print(f"update.py: {e}", file=sys.stderr)
        return 2
    for name, c in res:
        print_one(name, c)
    failed = [n for n, c in res if not c.ok]
    print(f"RESULT: {'PASS' if not failed else 'FAIL'} ({len(res) - len(failed)} passed, {len(failed)} failed)")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({n: {"ok": c.ok, "name": c.name, "checks": c.items, "info": c.info} for n, c in res}, f,
                      indent=1, default=lambda o: o.hex() if isinstance(o, bytes) else str(o))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
