#!/usr/bin/env python3
"""Tests of tools/fw-check/update.py: the image and report helpers, the three scenarios end to end on a synthetic
bootloader (hand-assembled Thumb-2: the boot state check, an image check, embassy-boot's page-by-page swap with the
IWDG fed around each erase, the boot report, the jump through VTOR; its "signature" is a 32-bit word sum, not
Ed25519/SHA-512) and two synthetic applications, and the scenarios on the REAL ELFs when they exist:

    FW_BOOTLOADER_ELF=.../bootloader FW_ELF=.../firmware [FW_APP_IMAGE=app.img] \\
    FW_NEW_APP_ELF=.../firmware-v2 FW_UPDATE_IMAGE=v2.img python3 -m pytest -q tools/fw-check/test_update.py

(defaults: target/thumbv7em-none-eabihf/fw/bootloader and .../firmware; the swap and refuse tests need the second
build and its signed image, signed with the key the bootloader was built with, and are skipped without them.)
"""

import hashlib
import io
import os
import struct
import sys
import unittest
from contextlib import redirect_stderr, redirect_stdout

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import boot  # noqa: E402
import update as up  # noqa: E402
from test_boot import POLL  # noqa: E402
from test_flash import (FLASH_IF, HAVE_TOOLS, IDLE, RES, UNLOCK, FlashTestBase, erase, firmware, jump,  # noqa: E402
                        start_erase, wait)

ROOT = up.ROOT
BL_ELF = os.environ.get("FW_BOOTLOADER_ELF", up.DEFAULT_BOOTLOADER)
APP_ELF = os.environ.get("FW_ELF", up.DEFAULT_APP)
APP_IMAGE = os.environ.get("FW_APP_IMAGE")
NEW_APP_ELF = os.environ.get("FW_NEW_APP_ELF")
NEW_IMAGE = os.environ.get("FW_UPDATE_IMAGE")


def sum32(payload: bytes) -> int:
    return sum(struct.unpack(f"<{len(payload) // 4}I", payload)) & 0xFFFF_FFFF


def make_image(payload: bytes, version: int, board: int = 0x1405, sha512: bool = False) -> bytes:
    """A header as docs/update.md lays it out; the hash field holds the payload's SHA-512 (`sha512`) or, for the
    synthetic bootloader, the payload's 32-bit word sum in its first word."""
    payload += b"\xff" * (-len(payload) % 4)
    h = bytearray(b"IMUF" + struct.pack("<HHIII", 1, 512, board, version, len(payload)))
    h += bytes(32 - len(h))
    h += hashlib.sha512(payload).digest() if sha512 else struct.pack("<I", sum32(payload)) + bytes(60)
    h += bytes(128 - len(h)) + bytes(64) + b"\xff" * 320
    return bytes(h) + payload


def elf_payload(elf: boot.Image) -> bytes:
    """The ELF's flash contents from ACTIVE + 0x200 on."""
    segs = elf.flash_segments()
    end = max(a + len(d) for a, d in segs)
    out = bytearray(b"\xff" * (end - (up.ACTIVE + up.HEADER_LEN)))
    for a, d in segs:
        out[a - up.ACTIVE - up.HEADER_LEN:a - up.ACTIVE - up.HEADER_LEN + len(d)] = d
    return bytes(out)


class HelperTests(unittest.TestCase):
    def test_parse_image(self):
        img = make_image(b"\x01\x02\x03\x04" * 10, 7, sha512=True)
        h = up.parse_image(img)
        self.assertTrue(h["valid"])
        self.assertTrue(h["sha512_ok"])
        self.assertEqual((h["version"], h["payload_len"], h["board_id"]), (7, 40, 0x1405))
        bad, off = up.flip_payload_byte(img)
        self.assertEqual(off, 20)
        self.assertFalse(up.parse_image(bad)["sha512_ok"])
        self.assertEqual(sum(a != b for a, b in zip(img, bad)), 1)
        self.assertFalse(up.parse_image(b"nope" + bytes(600))["valid"])
        with self.assertRaises(up.UpdateError):
            up.flip_payload_byte(img, 40)

    def test_parse_report(self):
        words = [0xB007_2E90, 3, 7, 1, 2, 0x4FF8_D16F]  # shared::update::boot_report's test vector layout
        r = up.parse_report(struct.pack("<6I", *words))
        self.assertEqual((r["action_name"], r["refusal_name"], r["active_version"], r["dfu_version"]),
                         ("Refused", "Hash", 1, 2))
        for i, bad in ((5, 0), (0, 0), (1, 4), (2, 0x100)):
            w = list(words)
            w[i] = bad
            self.assertIsNone(up.parse_report(struct.pack("<6I", *w)))

    def test_cli_missing_files_is_a_usage_error(self):
        err = io.StringIO()
        with redirect_stderr(err), redirect_stdout(io.StringIO()):
            rc = up.main(["boot", "--bootloader", "/nonexistent/bootloader", "--app", "/nonexistent/app"])
        self.assertEqual(rc, 2)
        self.assertIn("no bootloader ELF at /nonexistent/bootloader", err.getvalue())


@unittest.skipUnless(HAVE_TOOLS, "needs llvm-mc, rust-lld and llvm-objdump")
class SyntheticUpdateTests(FlashTestBase):
    """update.py's scenarios end to end on a synthetic bootloader that does what the real one must."""

    def bootloader(self, feed: bool = True) -> str:
        copy = f"""copy:
  push {{lr}}
  bl feed
  lsls r0, r2, #3
  orr r0, r0, #2
  orr r0, r0, #0x200
{start_erase("1")}  bl feed
  ldr r0, =0x201
  str r0, [r4, #0x10]
  ldr r3, =32768
2: ldr r0, [r5], #4
  str r0, [r6], #4
{wait("3")}  lsls r0, r3, #22
  bne 4f
  bl feed
4: subs r3, #1
  bne 2b
  movs r0, #0
  str r0, [r4, #0x10]
  pop {{pc}}
"""
        erase_state = f"""  bl feed
{erase(4, 2, "5")}  bl feed
  ldr r0, =0x80000000
  str r0, [r4, #0x10]
"""
        # embassy-boot's swap, page by page: ACTIVE page 1 -> DFU page 2, DFU page 1 -> ACTIVE page 1, ACTIVE page 0
        # -> DFU page 1, DFU page 0 -> ACTIVE page 0 (from, to, the sector erased at `to`)
        swap = "".join(f"""  ldr r5, =0x{src:08X}
  ldr r6, =0x{dst:08X}
  movs r2, #{sector}
  bl copy
""" for src, dst, sector in ((0x0804_0000, 0x080A_0000, 9), (0x0808_0000, 0x0804_0000, 6),
                             (0x0802_0000, 0x0808_0000, 8), (0x0806_0000, 0x0802_0000, 5)))
        body = f"""  ldr r4, ={FLASH_IF}
  ldr r8, =0x40003000
  ldr r0, =0x5555
  str r0, [r8]
  movs r0, #{4 if feed else 0}
  str r0, [r8, #4]
  ldr r0, =4095
  str r0, [r8, #8]
  ldr r0, =0xCCCC
  str r0, [r8]
  movs r0, #0
  mov r9, r0
  mov r11, r0
  ldr r0, ={up.STATE}
  ldr r0, [r0]
  ldr r1, =0xF0F0F0F0
  cmp r0, r1
  bne report
  ldr r5, ={up.DFU}
  ldr r0, [r5]
  ldr r1, =0x46554D49
  cmp r0, r1
  bne bad_magic
  ldr r3, [r5, #16]
  lsrs r3, r3, #2
  add r6, r5, #512
  movs r1, #0
6: ldr r0, [r6], #4
  add r1, r1, r0
  subs r3, #1
  bne 6b
  ldr r0, [r5, #32]
  cmp r0, r1
  bne bad_hash
{UNLOCK}{swap}{erase_state}  movs r0, #1
  mov r9, r0
  b report
bad_magic:
  movs r0, #1
  b refuse
bad_hash:
  movs r0, #7
refuse:
  mov r11, r0
  movs r0, #3
  mov r9, r0
{UNLOCK}{erase_state}report:
  ldr r7, =0x20000000
  ldr r0, =0xB0072E90
  str r0, [r7]
  str r9, [r7, #4]
  str r11, [r7, #8]
  ldr r5, ={up.ACTIVE}
  bl version
  str r0, [r7, #12]
  ldr r5, ={up.DFU}
  bl version
  str r0, [r7, #16]
  ldr r0, =0x4FF8D16F
  str r0, [r7, #20]
{jump(up.ACTIVE + 0x200)}"""
        extra = f"""{copy}
version:
  ldr r0, [r5]
  ldr r1, =0x46554D49
  cmp r0, r1
  ite eq
  ldreq r0, [r5, #12]
  movne r0, #0
  bx lr
feed:
{"  ldr r0, =0xAAAA" + chr(10) + "  str r0, [r8]" if feed else "  nop"}
  bx lr
"""
        return self.build(firmware(body, extra=extra))

    def app(self, marker: int, pad: int) -> str:
        body = f"""  ldr r7, ={RES}
  movs r0, #{marker}
  str r0, [r7, #0x20]
{"  nop" + chr(10) * 1 if pad else ""}  bl {POLL.format(n=marker)}
  sev
{IDLE}"""
        return self.build(firmware(body, poll=marker), origin=up.ACTIVE + 0x200)

    def ctx(self, feed: bool = True, **kw):
        bl = boot.Image(self.bootloader(feed), need_stack=False)
        app1, app2 = boot.Image(self.app(1, 0)), boot.Image(self.app(2, 1))
        ctx = {"bootloader": bl, "app": app1, "new_app": app2, "virtual_s": 40.0, "timeout": 120.0,
               "app_image": make_image(elf_payload(app1), 1), "image": make_image(elf_payload(app2), 2),
               "run_kw": {"lsi_hz": 32_000.0, "flash_timing": "max", "bsy_polls": 1, "verbose": False}}
        ctx.update(kw)
        return ctx

    def assert_ok(self, c):
        self.assertTrue(c.ok, [(i["check"], i["measured"]) for i in c.items if not i["ok"]])

    def test_boot(self):
        c = up.s_boot(self.ctx())
        self.assert_ok(c)
        self.assertEqual(c.info["boot_report"]["report"]["active_version"], 1)
        self.assertEqual(c.info["flash"]["erase_count"], 0)

    def test_boot_without_the_app_image_reports_version_0(self):
        c = up.s_boot(self.ctx(app_image=None))
        self.assert_ok(c)
        self.assertEqual(c.info["boot_report"]["report"]["active_version"], 0)

    def test_swap(self):
        c = up.s_swap(self.ctx())
        self.assert_ok(c)
        fl = c.info["flash"]
        self.assertEqual(fl["erase_count"], 5)  # 4 pages + the state sector
        self.assertEqual(fl["programs"], 4 * 32768)
        self.assertAlmostEqual(fl["erase_s"], 4 * 2.0 + 1.1)
        self.assertAlmostEqual(fl["program_s"], 4 * 32768 * 100e-6, places=6)
        iw = c.info["iwdg"]
        self.assertTrue(iw["started_by_bootloader"])
        self.assertLess(iw["max_gap_s"], iw["timeout_s"])
        self.assertGreaterEqual(iw["max_gap_s"], 2.0)  # a 128 KiB erase between two feeds
        # DFU's first page is left as it was (the old image went one page up): its header is still the new one's
        self.assertEqual(c.info["boot_report"]["report"]["dfu_version"], 2)

    def test_refuse(self):
        c = up.s_refuse(self.ctx())
        self.assert_ok(c)
        self.assertEqual(c.info["boot_report"]["report"]["refusal_name"], "Hash")

    def test_a_bootloader_that_does_not_feed_the_watchdog_fails_the_swap(self):
        c = up.s_swap(self.ctx(feed=False))
        self.assertFalse(c.ok)
        bad = {i["check"] for i in c.items if not i["ok"]}
        self.assertIn("the IWDG never expired during the swap", bad)
        self.assertIn("no erase cut short", bad)

    def test_cli_all_with_files(self):
        ctx = self.ctx()
        d = os.path.dirname(ctx["app"].path)
        paths = {}
        for name in ("app_image", "image"):
            paths[name] = os.path.join(d, f"{name}.bin")
            with open(paths[name], "wb") as f:
                f.write(ctx[name])
        out = os.path.join(d, "update.json")
        with redirect_stdout(io.StringIO()) as so:
            rc = up.main(["all", "--bootloader", ctx["bootloader"].path, "--app", ctx["app"].path,
                          "--app-image", paths["app_image"], "--new-app", ctx["new_app"].path,
                          "--image", paths["image"], "--json", out])
        self.assertEqual(rc, 0, so.getvalue())
        self.assertIn("RESULT: PASS (3 passed, 0 failed)", so.getvalue())
        with redirect_stderr(io.StringIO()) as se:  # an image that is not --new-app's
            rc = up.main(["swap", "--bootloader", ctx["bootloader"].path, "--app", ctx["app"].path,
                          "--new-app", ctx["app"].path, "--image", paths["image"]])
        self.assertEqual(rc, 2)
        self.assertIn("its payload is not", se.getvalue())


def real_ctx(need_new: bool):
    for path, what in ((BL_ELF, "bootloader ELF (set FW_BOOTLOADER_ELF)"), (APP_ELF, "application ELF (set FW_ELF)")):
        if not os.path.isfile(path):
            raise unittest.SkipTest(f"no {what} at {path}")
    if need_new and not (NEW_APP_ELF and NEW_IMAGE and os.path.isfile(NEW_APP_ELF) and os.path.isfile(NEW_IMAGE)):
        raise unittest.SkipTest("swap/refuse need FW_NEW_APP_ELF (a second application build) and FW_UPDATE_IMAGE "
                                "(its image from `ground fw-sign`, signed with the bootloader's key)")
    argv = ["all" if need_new else "boot", "--bootloader", BL_ELF, "--app", APP_ELF]
    if APP_IMAGE:
        argv += ["--app-image", APP_IMAGE]
    if need_new:
        argv += ["--new-app", NEW_APP_ELF, "--image", NEW_IMAGE]
    return up.build_ctx(up.parser().parse_args(argv), ["swap", "refuse"] if need_new else ["boot"])


class RealElfUpdateTests(unittest.TestCase):
    def run_one(self, name, need_new):
        ctx = real_ctx(need_new)
        (n, c), = up.run_scenarios([name], ctx)
        self.assertTrue(c.ok, [(i["check"], i["measured"]) for i in c.items if not i["ok"]])

    def test_boot(self):
        self.run_one("boot", False)

    def test_swap(self):
        self.run_one("swap", True)

    def test_refuse(self):
        self.run_one("refuse", True)


if __name__ == "__main__":
    unittest.main(verbosity=2)
