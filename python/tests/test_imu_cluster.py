"""imu_cluster against independent references: allantools, the CSV/JSON/TOML files the `ground` CLI writes for the
same input (parsed here by numpy and the json module), and the real MIMU4444 data when /work/shared is present."""

import json
import os
import pathlib

import allantools
import numpy as np
import pytest

import imu_cluster

MIMU = pathlib.Path(os.environ.get("MIMU4444_DIR", "/work/shared/data/mimu4444"))


def csv_table(path):
    """A CSV as {column: float array} (numpy's parser; empty cells NaN)."""
    a = np.genfromtxt(path, delimiter=",", names=True, dtype=float, comments=None)
    return {n: np.atleast_1d(a[n]) for n in a.dtype.names}


def max_rel(a, b):
    return float(np.max(np.abs(a - b) / np.abs(b)))


def test_read_matches_the_csv(static_csv):
    t, data, cols = imu_cluster.read(static_csv)
    ref = csv_table(static_csv)
    assert data.shape == (12000, len(cols)) and len(cols) == 96
    np.testing.assert_array_equal(t, ref["t"])
    for i, c in enumerate(cols):
        np.testing.assert_array_equal(data[:, i], ref[c], err_msg=c)


def test_read_npy(work):
    rng = np.random.default_rng(3)
    a = np.column_stack([np.arange(50) / 10.0, rng.normal(size=(50, 6))])
    p = work / "one_group.npy"
    np.save(p, a)
    t, data, cols = imu_cluster.read(p)
    np.testing.assert_array_equal(t, a[:, 0])
    assert cols == ["g00x", "g00y", "g00z", "a00x", "a00y", "a00z"]
    np.testing.assert_array_equal(data, a[:, 1:])


def test_allan_matches_allantools(static_csv):
    """Same column, same taus: deviations within 1e-9 relative of allantools (printed: the measured maximum)."""
    t, data, cols = imu_cluster.read(static_csv)
    rate = 1.0 / np.median(np.diff(t))
    worst = 0.0
    for kind in ("adev", "oadev", "mdev"):
        y = data[:, cols.index("g03x")]
        ours = imu_cluster.allan(y, rate, kind=kind, taus="octave")
        taus, dev, _, n = getattr(allantools, kind)(y, rate=rate, data_type="freq", taus="octave")
        np.testing.assert_allclose(ours["taus"], taus, rtol=1e-12)
        np.testing.assert_array_equal(ours["n"], n)
        worst = max(worst, max_rel(ours["dev"], dev))
        assert np.all(ours["ci_lo"][np.isfinite(ours["ci_lo"])] <= ours["dev"][np.isfinite(ours["ci_lo"])])
    print(f"allan vs allantools: max relative difference {worst:.3e}")
    assert worst <= 1e-9


def test_decode_matches_ground_decode(ground, work, telemetry):
    fused_csv, nav_csv = work / "fused.csv", work / "nav.csv"
    ground("decode", telemetry, "--out", fused_csv, "--nav", nav_csv)
    d = imu_cluster.decode(telemetry)
    f, ref = d["fused"], csv_table(fused_csv)
    assert len(f["seq"]) == len(ref["seq"]) > 100
    np.testing.assert_array_equal(f["seq"], ref["seq"])
    for i, c in enumerate(["gx_udps", "gy_udps", "gz_udps"]):
        np.testing.assert_array_equal(f[f"rate_udps.{i}"], ref[c])
    nav = csv_table(nav_csv)
    assert len(d["nav"]["seq"]) == len(nav["seq"]) > 100
    np.testing.assert_allclose(d["nav"]["dtheta_nrad.0"] * 1e-9, nav["dtheta_x_rad"], atol=1e-9)
    assert set(d) >= {"fused", "nav", "allan", "health", "housekeeping", "time", "stats"}
    assert d["stats"]["kiss_errors"] == 0 and d["stats"]["frames"] > 0
    jsonl = work / "all.jsonl"
    ground("decode", telemetry, "--out", jsonl)
    kinds = [next(iter(json.loads(l))) for l in jsonl.read_text().splitlines()]
    for k in ("Health", "Housekeeping"):
        got = len(next(iter(d[k.lower()].values()), []))
        assert got == kinds.count(k), k
    assert kinds.count("Health") > 0


def test_diagnose_is_the_cli_json(ground, work, static_csv):
    j = work / "diag.json"
    ground("diagnose", static_csv, "--json", j, "--out", work / "diag-out")
    ours = imu_cluster.diagnose(static_csv)
    assert ours == json.loads(j.read_text())
    t, data, cols = imu_cluster.read(static_csv)
    from_array = imu_cluster.diagnose(data, rate=1.0 / np.median(np.diff(t)))
    assert from_array.keys() == ours.keys()


def test_model_load_save_and_simulate(ground, work, static_csv):
    m_cli = work / "model.toml"
    ground("diagnose", static_csv, "--model", m_cli, "--out", work / "diag-out2")
    m = imu_cluster.Model.load(m_cli)
    again = work / "again.toml"
    m.save(again)
    assert again.read_text() == m_cli.read_text()
    sim_csv = work / "sim.csv"
    ground("simulate", "--model", m_cli, "--samples", 2000, "--seed", 7, "--out", sim_csv)
    ours = imu_cluster.simulate(m, samples=2000, seed=7)
    _, ref, _ = imu_cluster.read(sim_csv)
    ref_tab = csv_table(sim_csv)
    assert ours.shape == ref.shape
    np.testing.assert_allclose(ours[:, 0], ref_tab["g00x"], rtol=0, atol=1e-9)
    # The CSV holds 9 decimals (°/s, g).
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)


def test_simulate_preset_is_the_cli_csv(ground, work):
    p = work / "seed.csv"
    ground("simulate", "--out", p, "--samples", 500, "--seed", 2)
    ours = imu_cluster.simulate("seed", samples=500, seed=2)
    _, ref, _ = imu_cluster.read(p)
    # The CSV holds 9 decimals (°/s, g).
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)


def test_errors_carry_the_library_message(work):
    missing = work / "missing.csv"
    with pytest.raises(imu_cluster.Error, match="missing.csv"):
        imu_cluster.read(missing)
    with pytest.raises(imu_cluster.Error, match="expected adev, oadev or mdev, found 'bogus'"):
        imu_cluster.allan(np.zeros(100), 1.0, kind="bogus")
    with pytest.raises(imu_cluster.Error, match="points per decade, found 'weekly'"):
        imu_cluster.allan(np.zeros(100), 1.0, taus="weekly")
    empty = work / "empty.kiss"
    empty.write_bytes(b"\x00" * 10)
    with pytest.raises(imu_cluster.Error, match="no telemetry message in 10 bytes"):
        imu_cluster.decode(empty)
    assert issubclass(imu_cluster.Error, ValueError)


@pytest.mark.skipif(not (MIMU / "exp_1" / "data.bin").exists(), reason=f"real MIMU4444 data absent ({MIMU})")
def test_real_mimu4444_allan_matches_allantools():
    t, data, cols = imu_cluster.read(MIMU / "exp_1" / "data.bin")
    assert data.shape[0] > 1000 and "g00x" in cols
    rate = 1.0 / np.median(np.diff(t))
    y = data[:, cols.index("g00x")]
    ours = imu_cluster.allan(y, rate)
    taus, dev, _, _ = allantools.oadev(y, rate=rate, data_type="freq", taus="octave")
    np.testing.assert_allclose(ours["taus"], taus, rtol=1e-12)
    worst = max_rel(ours["dev"], dev)
    print(f"MIMU4444 exp_1 g00x: max relative difference {worst:.3e}")
    assert worst <= 1e-9


@pytest.mark.skipif(not (MIMU / "exp_5" / "data.bin").exists(), reason=f"real MIMU4444 data absent ({MIMU})")
def test_longest_static_diagnosis_is_the_cli_json(ground, work):
    # exp_5's longest static interval holds a knock (a shared disturbance): both sides diagnose its quiet part.
    stream = MIMU / "exp_5" / "data.bin"
    j = work / "diag-exp5.json"
    ground("diagnose", stream, "--longest-static", "--json", j, "--out", work / "diag-exp5")
    got = imu_cluster.diagnose(stream, longest_static=True)
    assert got == json.loads(j.read_text())
    assert got["samples"] < 1900  # 26.1 s of the 29.2-s interval at 62.5 Hz, not the whole stream
    with pytest.raises(imu_cluster.Error, match="MIMU4444"):
        imu_cluster.diagnose(np.zeros((100, 6)), rate=10.0, longest_static=True)
