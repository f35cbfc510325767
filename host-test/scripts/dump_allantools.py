#!/usr/bin/env python3
"""Dump allantools reference results for the OCXO test record into CSV fixtures.

Usage (from the crate root):   python3 scripts/dump_allantools.py
Requires `pip install allantools` (tested with allantools 2024.6, numpy 2.x, scipy 1.17).

Writes into testdata/allan-reference/:
  allantools_devs.csv   list,kind,m,tau,n,dev          (adev/oadev/mdev; lists octave, decade, explicit)
  allantools_noise.csv  m,alpha_int,alpha,d,rho         (autocorr_noise_id(y, m, data_type='freq'))
  allantools_edf.csv    kind,m,alpha,edf,lo,hi          (edf_greenhall with N = len(phase) = len(y)+1,
                                                         confidence_interval(dev, edf) with the default
                                                         ci = erf(1/sqrt(2)))
Only allantools' *outputs* are stored; the crate never runs or embeds allantools code.
"""
import contextlib
import io
import math
import os
import sys

import numpy as np
import allantools as at

HERE = os.path.dirname(os.path.abspath(__file__))
FIX = os.path.join(HERE, "..", "..", "testdata", "allan-reference")


def read_data(fn):
    with open(fn) as fh:
        return np.array([float(l) for l in fh if not l.startswith("#") and l.strip()])


def s32_ms(fn):
    ms = []
    with open(fn) as fh:
        for l in fh:
            if l.startswith("#") or not l.strip():
                continue
            ms.append(int(float(l.split()[0])))
    return ms


def quiet(fun, *a, **kw):
    with contextlib.redirect_stdout(io.StringIO()):
        return fun(*a, **kw)


KINDS = {
    # kind: (function, overlapping, modified)
    "adev": (at.adev, False, False),
    "oadev": (at.oadev, True, False),
    "mdev": (at.mdev, True, True),
}


def max_m(kind, n):
    # largest m for which allantools keeps the point (n_terms >= 2)
    if kind == "adev":
        return n // 3
    if kind == "oadev":
        return (n - 1) // 2
    return n // 3


def main():
    f = read_data(os.path.join(FIX, "ocxo_frequency.txt"))
    y = np.array(at.frequency2fractional(f, mean_frequency=1.0e7))
    N = len(y)
    many = sorted(set(s32_ms(os.path.join(FIX, "stable32_oadev_alltau.txt"))
                      + s32_ms(os.path.join(FIX, "stable32_adev_alltau.txt"))))
    dev_rows = []
    edf_rows = []
    all_ms = set()
    for kind, (fun, ov, mod) in KINDS.items():
        for lst in ("octave", "decade"):
            taus, devs, errs, ns = quiet(fun, y, rate=1.0, data_type="freq", taus=lst)
            for t, d, n in zip(taus, devs, ns):
                dev_rows.append((lst, kind, int(round(t)), float(t), int(n), float(d)))
        mm = max_m(kind, N)
        explicit = sorted(set([m for m in many if m <= mm] + [mm, mm - 1, mm - 2, mm // 2 + 1]))
        for m in explicit:
            taus, devs, errs, ns = quiet(fun, y, rate=1.0, data_type="freq", taus=[float(m)])
            assert len(taus) == 1 and int(round(taus[0])) == m
            d = devs[0]
            dev_rows.append(("explicit", kind, m, float(taus[0]), int(ns[0]), float(d)))
            all_ms.add(m)
            for alpha in (2, 1, 0, -1, -2):
                try:
                    edf = quiet(at.edf_greenhall, alpha=alpha, d=2, m=m, N=N + 1,
                                overlapping=ov, modified=mod)
                except (NotImplementedError, AssertionError):
                    continue
                lo, hi = at.confidence_interval(d, edf)
                edf_rows.append((kind, m, alpha, float(edf), float(lo), float(hi)))
    noise_rows = []
    for m in sorted(all_ms):
        try:
            a_int, a, dd, rho = quiet(at.autocorr_noise_id, y, m, data_type="freq", dmin=0, dmax=2)
        except NotImplementedError:
            continue
        noise_rows.append((m, int(a_int), float(a), int(dd), float(rho)))

    with open(os.path.join(FIX, "allantools_devs.csv"), "w") as fh:
        fh.write("# allantools %s: deviations of ocxo_frequency.txt, y=(f-1e7)/1e7, tau0=1 s\n" % at.__version__)
        fh.write("list,kind,m,tau,n,dev\n")
        for r in dev_rows:
            fh.write("%s,%s,%d,%r,%d,%r\n" % r)
    with open(os.path.join(FIX, "allantools_noise.csv"), "w") as fh:
        fh.write("# allantools %s: autocorr_noise_id(y, m, data_type='freq', dmin=0, dmax=2)\n" % at.__version__)
        fh.write("m,alpha_int,alpha,d,rho\n")
        for r in noise_rows:
            fh.write("%d,%d,%r,%d,%r\n" % r)
    with open(os.path.join(FIX, "allantools_edf.csv"), "w") as fh:
        fh.write("# allantools %s: edf_greenhall(alpha, d=2, m, N=len(y)+1, ...) and "
                 "confidence_interval(dev, edf) (ci=erf(1/sqrt 2))\n" % at.__version__)
        fh.write("kind,m,alpha,edf,lo,hi\n")
        for r in edf_rows:
            fh.write("%s,%d,%d,%r,%r,%r\n" % r)
    print("devs", len(dev_rows), "noise", len(noise_rows), "edf", len(edf_rows), file=sys.stderr)


if __name__ == "__main__":
    main()
