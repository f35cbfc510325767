#!/usr/bin/env python3
"""The allantools side of the benchmark: what `ground allan REC --kind oadev --taus octave` computes, done with
allantools on the same interchange CSV or NumPy .npy array (t, then gx gy gz ax ay az per group, as `ground` reads
it): octave OADEV of every sensor column and of the cluster mean of each axis.

allantools' `oadev` returns deviations and its simple error estimate; the noise identification, Greenhall EDF and
chi-squared intervals that `ground allan` also computes are NOT done here, so this side does less work.
Usage: allantools_allan.py REC.csv|REC.npy OUT.csv
"""
import sys, time
import numpy as np
import allantools

t0 = time.time()
if sys.argv[1].endswith(".npy"):
    a = np.load(sys.argv[1])
    names = ["t"] + [f"{k}{g:02}{x}" for g in range((a.shape[1] - 1) // 6) for k in "ga" for x in "xyz"]
    data = {n: a[:, j] for j, n in enumerate(names)}
else:
    import pandas as pd

    data = pd.read_csv(sys.argv[1], engine="c")
t_read = time.time() - t0
t = np.asarray(data["t"])
rate = 1.0 / np.median(np.diff(t))
cols = [c for c in data.keys() if len(c) == 4 and c[0] in "ga" and c[1:3].isdigit() and c[3] in "xyz"]
series = {c: np.asarray(data[c]) for c in cols}
for kind in "ga":
    for ax in "xyz":
        members = [series[c] for c in cols if c[0] == kind and c[3] == ax]
        if members:
            series[f"mean_{kind}{ax}"] = np.mean(members, axis=0)
rows = []
for name, y in series.items():
    taus, devs, errs, ns = allantools.oadev(y, rate=rate, data_type="freq", taus="octave")
    rows += [(name, tau, n, d) for tau, d, n in zip(taus, devs, ns)]
with open(sys.argv[2], "w") as out:
    out.write("column,tau_s,n,dev\n")
    out.writelines(f"{c},{float(tau)!r},{int(n)},{float(d)!r}\n" for c, tau, n, d in rows)
print(f"allantools: {len(series)} series, read {t_read:.1f} s, total {time.time() - t0:.1f} s")
