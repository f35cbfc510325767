#!/usr/bin/env bash
# Side-by-side: `ground allan` vs allantools on the same paper-size file (545,410 samples × 96 sensor columns +
# 6 cluster means = 102 series, octave OADEV). Generates the CSV with `ground simulate` if it is missing; a .npy
# (t, then gx gy gz ax ay az per group) is made from it with numpy when FILE.npy is asked for and missing.
# Needs: pip install allantools==2024.6 pandas. Usage: host-test/scripts/bench_allan.sh [FILE.csv|FILE.npy]
set -euo pipefail
cd "$(dirname "$0")/../.."
rec=${1:-target/bench/seed8h.csv}
mkdir -p target/bench
cargo build --release -q --bin ground
csv=${rec%.npy}
[ "$csv" = "$rec" ] || csv=$csv.csv
if [ ! -f "$csv" ] && [ ! -f "$rec" ]; then
  ./target/release/ground simulate --preset seed --out "$csv"
fi
if [ ! -f "$rec" ]; then
  python3 -c 'import sys, pandas as pd, numpy as np
df = pd.read_csv(sys.argv[1], engine="c")
np.save(sys.argv[2], df[[c for c in df.columns if c != "temp_c"]].to_numpy(dtype="<f8"))' "$csv" "$rec"
fi
ls -l "$rec"
echo "== ground allan (octave OADEV + noise id + Greenhall EDF + 68 % CI + noise fit, all cores)"
/usr/bin/time -f "ground: %e s wall, %M KiB max RSS" ./target/release/ground allan "$rec" --kind oadev --taus octave --out target/bench/ground_adev.csv
echo "== ground allan, one core"
/usr/bin/time -f "ground (1 thread): %e s wall" env RAYON_NUM_THREADS=1 ./target/release/ground allan "$rec" --kind oadev --taus octave --out target/bench/ground_adev1.csv > /dev/null
echo "== allantools (octave OADEV only)"
/usr/bin/time -f "allantools: %e s wall, %M KiB max RSS" python3 host-test/scripts/allantools_allan.py "$rec" target/bench/allantools_adev.csv
echo "== agreement"
python3 - <<'PY'
import pandas as pd, numpy as np
g = pd.read_csv("target/bench/ground_adev.csv"); a = pd.read_csv("target/bench/allantools_adev.csv")
m = g.merge(a, on=["column", "n"], suffixes=("_g", "_a"))
rel = np.abs(m.dev_g / m.dev_a - 1)
print(f"{len(m)} common (column, tau) points; max relative difference {rel.max():.2e}")
PY
