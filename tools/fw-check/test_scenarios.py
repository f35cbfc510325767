#!/usr/bin/env python3
"""Short runs of scenarios.py / faults.py on the real ELFs (skipped when an ELF or the ground binary is missing).

    FW_ELF=/tmp/elf/firmware FW_INJECT_ELF=/tmp/elf/firmware-inject python3 -m pytest -q tools/fw-check/test_scenarios.py

The full processor-in-the-loop test (≥ 3 000 frames) and every fault scenario run from the command line in CI
(`scenarios.py pil`, `scenarios.py faults`); here a shorter PIL and the cheap scenarios, so that the test suite
stays quick.
"""

import argparse
import os
import shutil
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import boot  # noqa: E402
import faults  # noqa: E402
import scenarios as sc  # noqa: E402

ROOT = sc.ROOT
FW_ELF = os.environ.get("FW_ELF", os.path.join(ROOT, "target/thumbv7em-none-eabihf/fw/firmware"))
FW_INJECT_ELF = os.environ.get("FW_INJECT_ELF",
                               os.path.join(ROOT, "target/fault-injection/thumbv7em-none-eabihf/fw/firmware"))
GROUND = sc.find_ground()


def has_reset_history(path):
    """The FDIR firmware (protocol 4: Housekeeping.clock_source, Telemetry::Resets) has a naked HardFault with
    its own stack; older ELFs do not."""
    img = boot.Image(path)
    return any("FAULT_STACK" in n for n in img.addr_of)


@unittest.skipUnless(os.path.isfile(FW_ELF), f"no flight ELF at {FW_ELF} (set FW_ELF)")
@unittest.skipUnless(GROUND, "no ground binary (set GROUND or build target/release/ground)")
class FlightElfScenarios(unittest.TestCase):
    def setUp(self):
        self.work = tempfile.mkdtemp(prefix="test-scen-")
        self.addCleanup(shutil.rmtree, self.work, True)

    def test_short_pil(self):
        # 400 frames: 12 Fused/Nav reports and the full Allan dump, bit-identical to ground replay
        res = sc.pil(FW_ELF, boot.synth_frames(400), GROUND, self.work, timeout_s=120)
        self.assertEqual(res.get("error"), None)
        for k in ("Fused", "Nav", "Allan"):
            self.assertTrue(res["compare"][k]["equal"], res["compare"][k])
            self.assertGreater(res["compare"][k]["firmware"], 0)
        self.assertTrue(res["ok"], res)

    def test_flight_elf_has_no_injection_symbols(self):
        self.assertEqual(faults.injection_symbols(boot.Image(FW_ELF)), [])

    @unittest.skipUnless(os.path.isfile(FW_ELF) and has_reset_history(FW_ELF), "ELF without the reset history")
    def test_dead_crystal_and_css(self):
        res = dict(faults.run_all(None, FW_ELF, GROUND, only=["hse-dead", "css", "idle-config"]))
        for name, c in res.items():
            self.assertTrue(c.ok, (name, c.items))


@unittest.skipUnless(os.path.isfile(FW_INJECT_ELF), f"no fault-injection ELF at {FW_INJECT_ELF} (set FW_INJECT_ELF)")
@unittest.skipUnless(GROUND, "no ground binary")
class InjectionScenarios(unittest.TestCase):
    def test_panic_and_bad_address(self):
        if faults.inject_address(boot.Image(FW_INJECT_ELF)) is None:
            self.skipTest(f"{FW_INJECT_ELF} has no {faults.INJECT_SYMBOL} symbol")
        res = dict(faults.run_all(FW_INJECT_ELF, FW_ELF if os.path.isfile(FW_ELF) else None, GROUND,
                                  only=["panic", "bad-address"]))
        for name, c in res.items():
            self.assertTrue(c.ok, (name, c.items))


class CliTests(unittest.TestCase):
    def test_pil_needs_ground(self):
        old = os.environ.get("GROUND")
        os.environ["GROUND"] = "/nonexistent/ground"
        try:
            a = argparse.Namespace(ground=None, elf="x", frames="synth:10", min_frames=0, json=None, timeout=1,
                                   keep=False, verbose=False)
            if not os.path.isfile(os.path.join(ROOT, "target/release/ground")):
                self.assertEqual(sc.cmd_pil(a), 2)
        finally:
            if old is None:
                del os.environ["GROUND"]
            else:
                os.environ["GROUND"] = old

    def test_too_few_frames_is_a_usage_error(self):
        if not GROUND:
            self.skipTest("no ground binary")
        a = argparse.Namespace(ground=GROUND, elf="x", frames="synth:10", min_frames=3000, json=None, timeout=1,
                               keep=False, verbose=False)
        self.assertEqual(sc.cmd_pil(a), 2)


if __name__ == "__main__":
    unittest.main(verbosity=2)
