#!/usr/bin/env python3
"""Scenarios on the REAL firmware ELF in emulation (`emu.Sim`): the processor-in-the-loop differential test and
the fault-injection scenarios of the FDIR issue.

    python3 tools/fw-check/scenarios.py pil ELF [--frames FILE|synth:N|sim:SECONDS] [--json out.json]
    python3 tools/fw-check/scenarios.py faults INJECT_ELF --flight FLIGHT_ELF [--only NAME ...] [--json out.json]

`pil`: an FPGA frame stream (a `ground simulate` record by default, ≥ 3 000 frames) goes into USART1's RX DMA ring
at 604.8 frames/s of virtual time; after the last frame, an `AllanRequest { first: 0, count: 102 }` (tag 1) goes
into USART2's RX DMA ring (DMA1 stream 5) as the ground sends it: `[PROTOCOL_VERSION] ++ postcard(CommandEnvelope)`
in a CSP v1 packet (ground node 1 -> node 10, port 11, link CRC-32C) in a KISS frame. Everything the firmware
transmits on USART2 is decoded with `ground decode` (the project's decoder); `ground replay` of the same frames,
whose final dump is the same command with the same tag after the last frame, is decoded the same way. Its `Fused`,
`Nav` and `Allan` messages must be equal, in order and bit for bit (the JSON of equal postcard values); Health,
Housekeeping, acks and the replay's final HealthRequest answer are not compared. Exit status 0 only on equality.

`faults`: see faults.FAULT_SCENARIOS (each one asserts what the next boot reports in Housekeeping and its reset
history); scenarios that need the fault-injection build are skipped, with the reason, when it is missing or has no
`FDIR_INJECT` symbol. Exit status 0 when no scenario failed.

In CI (host times measured on the 2-core build machine under load; the emulator ≈ 4.5 ms host per FPGA frame):
    python tools/fw-check/scenarios.py pil target/thumbv7em-none-eabihf/fw/firmware --json pil.json      # ≈ 22 s
    python tools/fw-check/scenarios.py faults target/fault-injection/thumbv7em-none-eabihf/fw/firmware \
        --flight target/thumbv7em-none-eabihf/fw/firmware --json faults.json                               # ≈ 80 s
(`--only NAME` runs one scenario. Of the 80 s, line-noise takes ≈ 68 s with the 00:20 firmware, which re-reads
stale ring data after each error, and ≈ 24 s when the ring restart is consistent; every other scenario ≤ 3 s.)

Needs the `ground` binary: $GROUND, else target/release/ground of this repository.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import boot  # noqa: E402
import emu  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(HERE))
FRAME_HZ = 604.8
FRAME_LEN = 240
BUS_BAUD = 115_200
ALLAN_CHANNELS = 102
ALLAN_REQUEST = 7  # variant index of Command::AllanRequest (shared/src/telemetry.rs)


class ScenarioError(Exception):
    """A tooling problem (exit status 2)."""


def find_ground() -> str | None:
    g = os.environ.get("GROUND") or os.path.join(ROOT, "target/release/ground")
    return g if os.path.isfile(g) and os.access(g, os.X_OK) else None


def sim_args(**kw) -> argparse.Namespace:
    a = argparse.Namespace(verbose=False, trace_mmio=False, spin_limit=200_000, max_stack_percent=80.0,
                           require_iwdg_before_clock=False, json=None)
    a.__dict__.update(kw)
    return a


def new_sim(elf: str, img=None, **kw) -> emu.Sim:
    img = img or boot.Image(elf)
    m = emu.Sim(img, sim_args(verbose=kw.pop("verbose", False)), **kw)
    m.power_on()
    return m


# -- the bus, as the ground sends it (shared/src/bus: CSP v1 in KISS; docs/bus.md) -------------------------------

def varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def csp_v1_header(prio: int, src: int, dst: int, dport: int, sport: int, flags: int = 0) -> bytes:
    return ((prio << 30) | (src << 25) | (dst << 20) | (dport << 14) | (sport << 8) | flags).to_bytes(4, "big")


def kiss(data: bytes) -> bytes:
    return b"\xc0\x00" + data.replace(b"\xdb", b"\xdb\xdd").replace(b"\xc0", b"\xdb\xdc") + b"\xc0"


def command_frame(payload: bytes) -> bytes:
    """A command payload as bus bytes: CSP v1 from the ground (node 1, port 10) to node 10's command port 11,
    the KISS link CRC-32C (big-endian) over the payload, in a KISS frame."""
    return kiss(csp_v1_header(2, 1, 10, 11, 10) + payload + boot.crc32c(payload).to_bytes(4, "big"))


def allan_request(version: int, tag: int = 1, first: int = 0, count: int = ALLAN_CHANNELS) -> bytes:
    """`[version] ++ postcard(CommandEnvelope { tag, cmd: AllanRequest { first, count } })` on the bus."""
    return command_frame(bytes([version]) + varint(tag) + varint(ALLAN_REQUEST) + bytes([first, count]))


def send_bus(m: emu.Sim, data: bytes, t: float):
    m.feed_rx("USART2", "DMA1", 5, data, t, BUS_BAUD)


def feed_frames(m: emu.Sim, stream: bytes, t0: float, rate: float = FRAME_HZ, noise=None):
    """FPGA frames into USART1 (DMA2 stream 2), one 240-byte burst per frame period from t0 (chained events, the
    line idle after each); noise(i, t) -> (bytes, flags) may replace a frame by garbage with line errors."""
    n = len(stream) // FRAME_LEN
    m.frames_fed = 0
    u1, dma2 = "USART1", "DMA2"

    def deliver(i):
        t = t0 + (i + 1) / rate
        data, flags = stream[i * FRAME_LEN:(i + 1) * FRAME_LEN], 0
        if noise is not None:
            data, flags = noise(i, t, data)
        u, d = m.block(u1), m.block(dma2)
        if data:
            u.bytes_in(d, 2, data, flags)
            u.idle = True
        m.frames_fed += 1
        m.poke()
        if i + 1 < n:
            m.at(t0 + (i + 2) / rate, lambda: deliver(i + 1))
    if n:
        m.at(t0 + 1 / rate, lambda: deliver(0))
    return t0 + n / rate


def bus_versions(m: emu.Sim) -> set:
    return {x.get("version") for x in m.bus_msgs if "version" in x}


# -- ground ------------------------------------------------------------------------------------------------------

def run_ground(ground: str, *argv, timeout=300) -> str:
    r = subprocess.run([ground, *argv], capture_output=True, text=True, timeout=timeout)
    if r.returncode != 0:
        raise ScenarioError(f"ground {' '.join(argv)}: exit {r.returncode}: {r.stderr.strip()[-800:]}")
    return r.stdout + r.stderr


def decode(ground: str, bus: bytes, work: str, name: str) -> list:
    path = os.path.join(work, f"{name}.kiss")
    with open(path, "wb") as f:
        f.write(bus)
    out = os.path.join(work, f"{name}.jsonl")
    try:
        run_ground(ground, "decode", path, "--out", out)
    except ScenarioError as e:
        if "no telemetry message" in str(e):
            return []  # a boot that ended before its first message
        raise
    with open(out) as f:
        return [json.loads(line) for line in f if line.strip()]


def kind(msg) -> str:
    return next(iter(msg)) if isinstance(msg, dict) and msg else str(msg)


def of_kind(msgs, k):
    return [m[k] if isinstance(m, dict) else m for m in msgs if kind(m) == k]


def make_frames(spec: str, ground: str | None, work: str) -> bytes:
    """synth:N (boot.synth_frames), sim:SECONDS (ground simulate at 604.8 frames/s, seed 7) or a file."""
    if spec.startswith("synth"):
        return boot.synth_frames(int(spec.split(":")[1]) if ":" in spec else 3200)
    if spec.startswith("sim"):
        if ground is None:
            raise ScenarioError("sim frames need the ground binary (set GROUND or build target/release/ground)")
        secs = spec.split(":")[1] if ":" in spec else "5.3"
        path = os.path.join(work, "rec.bin")
        run_ground(ground, "simulate", "--out", path, "--seconds", secs, "--rate", str(FRAME_HZ), "--seed", "7")
        with open(path, "rb") as f:
            return f.read()
    with open(spec, "rb") as f:
        return f.read()


# -- the processor-in-the-loop differential test -----------------------------------------------------------------

def pil(elf: str, frames: bytes, ground: str, work: str, *, timeout_s: float = 120.0, verbose=False) -> dict:
    t_host = time.monotonic()
    # the reference first: `ground replay` ends with AllanRequest { 0, 102 } (tag 1) after the last frame
    ref_bin = os.path.join(work, "frames.bin")
    with open(ref_bin, "wb") as f:
        f.write(frames)
    run_ground(ground, "replay", ref_bin, "--out", os.path.join(work, "replay.kiss"))
    with open(os.path.join(work, "replay.kiss"), "rb") as f:
        ref_bus = f.read()
    ref_raw = raw_messages(ref_bus)
    want_allan = sum(1 for k, _, _ in ref_raw if k == RAW_KINDS["Allan"])
    t_emu = time.monotonic()
    m = new_sim(elf, verbose=verbose, max_resets=0)
    res = {"elf": elf, "frames": len(frames) // FRAME_LEN}
    r = m.run_until(0.2, timeout_s=timeout_s)
    if r != "time":
        raise ScenarioError(f"boot did not run: {r}: {m.stop_msg}")
    t_end = feed_frames(m, frames, m.now())
    r = m.run_until(t_end + 0.3, timeout_s=timeout_s)
    res["frames_fed"] = m.frames_fed
    if r != "time":
        res.update(ok=False, error=f"run stopped while streaming: {r}: {m.stop_msg}")
        return res
    versions = bus_versions(m)
    if len(versions) != 1:
        res.update(ok=False, error=f"protocol version of the firmware's messages unclear: {versions}")
        return res
    version = versions.pop()
    t_cmd = m.now()
    send_bus(m, allan_request(version), t_cmd)
    n0 = sum(1 for x in m.bus_msgs if x.get("kind") == "Allan")
    m.run_until(t_cmd + 30.0, timeout_s=timeout_s,
                until=lambda: sum(1 for x in m.bus_msgs if x.get("kind") == "Allan") - n0 >= want_allan)
    m.run_until(m.now() + 0.2, timeout_s=timeout_s)  # the last transmission ends
    res["allan_dump_virtual_s"] = round(m.now() - t_cmd, 3)
    res["emulation_host_s"] = round(time.monotonic() - t_emu, 2)
    res["virtual_s"] = round(m.now(), 3)
    res["resets"] = len(m.boots) - 1
    res["bus_bytes"] = len(m.bus_tx)
    with open(os.path.join(work, "firmware.kiss"), "wb") as f:
        f.write(m.bus_tx)
    # 1. bit for bit: the postcard bodies of every Fused, Nav and Allan message, in order
    fw_raw = raw_messages(bytes(m.bus_tx))
    res["protocol_versions"] = {"firmware": sorted({v for _, v, _ in fw_raw if v is not None}),
                                "replay": sorted({v for _, v, _ in ref_raw if v is not None})}
    res["bad_packets_firmware"] = sum(1 for k, _, _ in fw_raw if k is None)
    ok = res["bad_packets_firmware"] == 0
    res["compare"] = {}
    for k, idx in RAW_KINDS.items():
        a = [b for v, _, b in fw_raw if v == idx]
        b = [x for v, _, x in ref_raw if v == idx]
        first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), None)
        if first is None and len(a) != len(b):
            first = min(len(a), len(b))
        c = res["compare"][k] = {"firmware": len(a), "replay": len(b), "equal": a == b, "first_difference": first}
        if first is not None:
            c["firmware_msg"] = a[first].hex() if first < len(a) else None
            c["replay_msg"] = b[first].hex() if first < len(b) else None
        ok &= a == b and len(a) > 0
    # the command's acknowledgement (tag 1): the same bytes
    ack = lambda raw: [b for v, _, b in raw if v == 4 and len(b) > 1 and b[1] == 1][:1]  # noqa: E731 (Ack, tag 1)
    a, b = ack(fw_raw), ack(ref_raw)
    res["compare"]["Ack(AllanRequest)"] = {"firmware": len(a), "replay": len(b), "equal": a == b and bool(a),
                                           "first_difference": None if a == b else 0}
    ok &= a == b and bool(a)
    # 2. the same through `ground decode` (readable, and the decoder's view), when it can read both streams
    same_version = res["protocol_versions"]["firmware"] == res["protocol_versions"]["replay"]
    if same_version:
        fw, ref = decode(ground, bytes(m.bus_tx), work, "firmware"), decode(ground, ref_bus, work, "replay")
        res["counts_firmware"], res["counts_replay"] = count_kinds(fw), count_kinds(ref)
        for k in RAW_KINDS:
            a, b = of_kind(fw, k), of_kind(ref, k)
            res["compare"][k]["decoded_equal"] = a == b
            if a != b:
                first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
                res["compare"][k]["firmware_msg"] = a[first] if first < len(a) else None
                res["compare"][k]["replay_msg"] = b[first] if first < len(b) else None
            ok &= a == b
    else:
        res["decode_skipped"] = ("the firmware's protocol version differs from this ground build's: compared as "
                                 "postcard bytes only")
    res["ok"] = bool(ok and res["resets"] == 0)
    res["host_s"] = round(time.monotonic() - t_host, 2)
    return res


def raw_messages(bus: bytes) -> list:
    """(variant index, protocol version, postcard body) of each telemetry message in KISS/CSP v1 bus bytes (the
    classification of boot.decode_bus_message; the bodies are compared as bytes, never decoded here)."""
    out = []
    for pkt in boot.kiss_frames(bus):
        if len(pkt) < 4 + 2 + 4:
            continue
        payload = pkt[4:-4]
        if boot.crc32c(payload) != int.from_bytes(pkt[-4:], "big"):
            out.append((None, None, pkt))
            continue
        if pkt[3] & 1:
            payload = payload[:-4]
        out.append((payload[1], payload[0], bytes(payload[1:])))
    return out


RAW_KINDS = {"Fused": 0, "Allan": 1, "Nav": 7}


def count_kinds(msgs) -> dict:
    out = {}
    for x in msgs:
        out[kind(x)] = out.get(kind(x), 0) + 1
    return out


def cmd_pil(a) -> int:
    ground = a.ground or find_ground()
    if ground is None:
        print("scenarios.py pil: no ground binary (set GROUND or --ground, or build target/release/ground)",
              file=sys.stderr)
        return 2
    work = tempfile.mkdtemp(prefix="pil-")
    try:
        frames = make_frames(a.frames, ground, work)
        if len(frames) // FRAME_LEN < a.min_frames:
            print(f"scenarios.py pil: only {len(frames) // FRAME_LEN} frames (< {a.min_frames})", file=sys.stderr)
            return 2
        res = pil(a.elf, frames, ground, work, timeout_s=a.timeout, verbose=a.verbose)
    except ScenarioError as e:
        print(f"scenarios.py pil: {e}", file=sys.stderr)
        return 2
    finally:
        if not a.keep:
            shutil.rmtree(work, True)
    print(f"pil: {a.elf}: {res['frames']} frames ({res.get('frames_fed')} fed), AllanRequest after the last; "
          f"{res.get('virtual_s')} s virtual, {res.get('host_s')} s host (emulation {res.get('emulation_host_s')} s)")
    if "error" in res:
        print(f"  ERROR {res['error']}")
    for k, c in res.get("compare", {}).items():
        good = c["equal"] and c["firmware"] and c.get("decoded_equal", True)
        print(f"  {'PASS' if good else 'FAIL'}  {k}: firmware {c['firmware']}, replay {c['replay']} messages, "
              + ("bit-identical postcard bodies" if c["equal"] else f"first difference at #{c['first_difference']}")
              + ("" if "decoded_equal" not in c else f"; ground decode {'equal' if c['decoded_equal'] else 'DIFFERS'}"))
        if not c["equal"]:
            print(f"     firmware: {json.dumps(c.get('firmware_msg'))[:400]}")
            print(f"     replay:   {json.dumps(c.get('replay_msg'))[:400]}")
    if res.get("decode_skipped"):
        print(f"  note: {res['decode_skipped']} (versions {res['protocol_versions']})")
    else:
        print(f"  decoded (ground decode): firmware {res.get('counts_firmware')}, replay {res.get('counts_replay')}")
    print("RESULT: " + ("PASS" if res["ok"] else "FAIL"))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1, default=str)
    return 0 if res["ok"] else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("pil", help="processor-in-the-loop differential test against ground replay")
    p.add_argument("elf")
    p.add_argument("--frames", default="sim:5.3", help="sim:SECONDS (ground simulate, default 5.3 s = 3205 "
                                                       "frames), synth:N, or a frame log")
    p.add_argument("--min-frames", type=int, default=3000)
    p.add_argument("--ground", help="the ground binary (default $GROUND or target/release/ground)")
    p.add_argument("--json")
    p.add_argument("--timeout", type=float, default=120.0, help="host-time budget per run segment, s")
    p.add_argument("--keep", action="store_true", help="keep the work directory")
    p.add_argument("-v", "--verbose", action="store_true")
    f = sub.add_parser("faults", help="fault-injection scenarios")
    f.add_argument("elf", help="the fault-injection build")
    f.add_argument("--flight", help="the flight build (checked for the absence of injection symbols)")
    f.add_argument("--only", action="append", help="run only these scenarios")
    f.add_argument("--ground")
    f.add_argument("--noise-s", type=float, help="line-noise duration, s (default 10)")
    f.add_argument("--noise-burst", type=int, default=4,
                   help="line noise arrives in bursts of this many frame periods (default 4: 6.6 ms, 960 bytes)")
    f.add_argument("--lsi-hz", type=float, default=32_000.0, help="the LSI (IWDG clock), Hz (nominal 32 kHz; "
                                                                  "17-47 kHz over parts and temperature)")
    f.add_argument("--dma-restart", choices=("f4", "resume-in-place", "resume-no-tcif"), default="f4",
                   help="a DMA stream re-enabled after a mid-transfer disable: f4 = restarts at M0AR with the NDTR "
                        "left, TCIF set at the disable (AN4031, the default); the others are what-ifs for diagnosis")
    f.add_argument("--json")
    f.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    if a.cmd == "pil":
        return cmd_pil(a)
    return cmd_faults(a)


def cmd_faults(a) -> int:
    import faults
    return faults.main_faults(a)


if __name__ == "__main__":
    sys.exit(main())
