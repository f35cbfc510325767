#!/usr/bin/env python3
"""The allantools side of the benchmark: what `ground allan REC --kind oadev --taus octave` computes, done with
allantools on the same interchange CSV: octave OADEV of every sensor column and of the cluster mean of each axis.

allantools' `oadev` returns deviations and its simple error estimate; the noise identification, Greenhall EDF and
chi-squared intervals that `ground allan` also computes are NOT done here, so this side does less work.
Usage: allantools_allan.py REC.csv OUT.csv
"""
import sys, time
import numpy as np
import pandas as pd
import allantools

t0 = time.time()
df = pd.read_csv(sys.argv[1], engine="c")
t_read = time.time() - t0
t = df["t"].to_numpy()
rate = 1.0 / np.median(np.diff(t))
cols = [c for c in df.columns if len(c) == 4 and c[0] in "ga" and c[1:3].isdigit() and c[3] in "xyz"]
series = {c: df[c].to_numpy() for c in cols}
for kind in "ga":
    for ax in "xyz":
        members = [series[c] for c in cols if c[0] == kind and c[3] == ax]
        if members:
            series[f"mean_{kind}{ax}"] = np.mean(members, axis=0)
rows = []
for name, y in series.items():
    taus, devs, errs, ns = allantools.oadev(y, rate=rate, data_type="freq", taus="octave")
    rows += [(name, tau, n, d) for tau, d, n in zip(taus, devs, ns)]
pd.DataFrame(rows, columns=["column", "tau_s", "n", "dev"]).to_csv(sys.argv[2], index=False)
print(f"allantools: {len(series)} series, read {t_read:.1f} s, total {time.time() - t0:.1f} s")
