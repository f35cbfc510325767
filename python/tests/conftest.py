"""Shared fixtures: the `ground` binary (the independent reference the tests compare against) and a work folder."""

import os
import pathlib
import shutil
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _ground() -> pathlib.Path:
    """`GROUND`, else the workspace's built `ground` (CARGO_TARGET_DIR or target/, debug then release)."""
    if os.environ.get("GROUND"):
        return pathlib.Path(os.environ["GROUND"])
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    for profile in ("debug", "release"):
        p = target / profile / "ground"
        if p.exists():
            return p
    found = shutil.which("ground")
    if found:
        return pathlib.Path(found)
    pytest.fail("no `ground` binary: run `cargo build --bin ground` first or set GROUND=/path/to/ground")


@pytest.fixture(scope="session")
def ground():
    """Runs `ground ARGS…` (which must succeed) and returns its stdout."""
    exe = _ground()

    def run(*args):
        out = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True)
        assert out.returncode == 0, f"ground {args} failed:\n{out.stderr}"
        return out.stdout

    return run


@pytest.fixture(scope="session")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("imu_cluster")


@pytest.fixture(scope="session")
def telemetry(ground, work):
    """A telemetry stream: 20 s of simulated frames at 604.8 Hz through the flight core (`ground replay`)."""
    frames, tm = work / "frames.bin", work / "tm.kiss"
    ground("simulate", "--out", frames, "--seconds", 20, "--rate", 604.8)
    ground("replay", frames, "--out", tm)
    return tm


@pytest.fixture(scope="session")
def static_csv(ground, work):
    """A static interchange CSV: the seed preset, 12,000 samples at 18.9 Hz (10.6 min)."""
    p = work / "static.csv"
    ground("simulate", "--out", p, "--samples", 12000, "--seed", 5)
    return p
