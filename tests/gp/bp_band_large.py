#!/usr/bin/env python3
"""The band of `csmetro reconstruct --method bp` at large n (one or two folds calibrate it):
compare_gp.py's generator stretched to n = 65,536 and 16,384 at 1 µm, 10 % sampled, σ = 0.02 µm.
Usage: python3 tests/gp/bp_band_large.py target/release/csmetro"""
import sys, os, json, subprocess, tempfile, time, numpy as np
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import compare_gp as g
exe = sys.argv[1]
for n, step in ((65536, 1.0), (16384, 1.0)):
    g.N, g.STEP = n, step
    g.X = np.arange(n) * step
    for fam in ("single", "rough", "steps"):
        truth = g.curve(fam, 0)
        r = np.random.default_rng(5)
        m = n // 10
        idx = np.sort(r.choice(n, m, replace=False))
        vals = truth[idx] + r.normal(0, 0.02, m)
        with tempfile.TemporaryDirectory() as tmp:
            s = os.path.join(tmp, "s.csv"); out = os.path.join(tmp, "r.csv")
            with open(s, "w") as f:
                f.write("position_um,error_um\n")
                for i, v in zip(idx, vals): f.write(f"{float(g.X[i])!r},{float(v)!r}\n")
            t = time.time()
            o = subprocess.run([exe, "reconstruct", "--grid", f"0:{step:g}:{g.X[-1]:g}", "--samples", s, "--method", "bp",
                                "--noise-um", "0.02", "--json", "--out", out], capture_output=True, text=True, check=True)
            wall = time.time() - t
            d = np.loadtxt(out, delimiter=",", skiprows=1)
            f = g.figures(d[:, 1], d[:, 2], truth)
            print(n, fam, m, {k: round(v, 4) for k, v in f.items()}, f"{wall:.1f} s", flush=True)
