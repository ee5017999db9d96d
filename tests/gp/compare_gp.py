#!/usr/bin/env python3
"""csmetro's pointwise band against scikit-learn's GaussianProcessRegressor, on the same samples.

Issue 51's peer: the model a statistician would pick for a position-dependent error with a
leadscrew's periodic part, Matern(5/2) + ExpSineSquared (periodic) + white noise, its
hyper-parameters by marginal likelihood (sklearn's L-BFGS-B, 2 restarts). Both see the same m
noisy samples of the same curve on a 1,901-point grid (0:5:9500 µm); csmetro runs
`csmetro reconstruct --method auto --json` (told the noise σ, nothing else); the GP is told the
noise σ as the white kernel's start and 400 µm as the period's start (a lab knows its leadscrew).

The curves come from this script's own generator (not csmetro's simulator, not its test
curves): trend + one or two periodic terms with harmonics, a chirp, steps and narrow defects,
white noise only, and correlated roughness.

Figures per method: coverage = share of the grid with |curve − truth| ≤ 2u; sharpness =
mean(2u) / mean |curve − truth|; mean |error|; wall time (csmetro: its own solve_ms, the GP:
fit + predict). Usage:

    python3 -m pip install scikit-learn
    cargo build --release
    python3 tests/gp/compare_gp.py --csmetro target/release/csmetro --seeds 3 --m 600
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

N, STEP = 1901, 5.0
X = np.arange(N) * STEP
FAMILIES = ["single", "two", "chirp", "steps", "noise", "rough"]


def curve(family, seed):
    """A truth on the grid (µm) from this script's own generator."""
    r = np.random.default_rng(1000 * seed + FAMILIES.index(family))
    t = X / X[-1]
    y = r.uniform(-3, 3) * t + r.uniform(-1, 1) * (t - 0.5) ** 2 * 4
    if family in ("single", "two", "steps"):
        p = r.uniform(150, 900)
        for h in (1, 2, 3):
            y += r.uniform(0.2, 1.5) / h * np.sin(2 * np.pi * h * X / p + r.uniform(0, 6.3))
    if family == "two":
        p2 = r.uniform(1500, 4000)
        y += r.uniform(0.5, 2.0) * np.sin(2 * np.pi * X / p2 + r.uniform(0, 6.3))
    if family == "chirp":
        f0, f1 = 1 / r.uniform(600, 1200), 1 / r.uniform(150, 300)
        phase = 2 * np.pi * (f0 * X + (f1 - f0) * X**2 / (2 * X[-1]))
        y += r.uniform(0.5, 1.5) * np.sin(phase)
    if family == "steps":
        for _ in range(3):
            c = r.uniform(500, 9000)
            y += r.uniform(0.3, 1.0) * np.sign(r.uniform(-1, 1)) * (X > c)
        for _ in range(2):
            c, w = r.uniform(500, 9000), r.uniform(10, 40)
            y += r.uniform(0.5, 1.5) * np.exp(-0.5 * ((X - c) / w) ** 2)
    if family == "noise":
        y = r.normal(0, 0.3, N)
    if family == "rough":
        w = r.normal(0, 1, N + 60)
        k = np.exp(-0.5 * (np.arange(-30, 31) / 8.0) ** 2)
        y += 0.6 * np.convolve(w, k / np.sqrt((k**2).sum()), mode="valid")[:N]
    return y


def figures(pred, u, truth):
    err = np.abs(pred - truth)
    return {
        "coverage": float(np.mean(err <= 2 * u)),
        "sharpness": float(np.mean(2 * u) / max(np.mean(err), 1e-12)),
        "mean_abs_error_um": float(np.mean(err)),
    }


def run_csmetro(exe, idx, vals, sigma, tmp):
    s = os.path.join(tmp, "s.csv")
    out = os.path.join(tmp, "r.csv")
    with open(s, "w") as f:
        f.write("position_um,error_um\n")
        for i, v in zip(idx, vals):
            f.write(f"{float(X[i])!r},{float(v)!r}\n")
    o = subprocess.run(
        [exe, "reconstruct", "--grid", f"0:{STEP:g}:{X[-1]:g}", "--samples", s,
         "--noise-um", str(sigma), "--json", "--out", out],
        capture_output=True, text=True, check=True)
    j = json.loads(o.stdout)
    d = np.loadtxt(out, delimiter=",", skiprows=1)
    if d.shape[1] < 3:
        sys.exit("csmetro wrote no u_um column")
    return d[:, 1], d[:, 2], j["solve_ms"] / 1e3, j["method"]


def run_gp(idx, vals, sigma):
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import (ConstantKernel as C, ExpSineSquared, Matern,
                                                  WhiteKernel)
    k = (C(1.0, (1e-4, 1e3)) * Matern(500.0, (5.0, 2e4), nu=2.5)
         + C(1.0, (1e-4, 1e3)) * ExpSineSquared(200.0, 400.0, (5.0, 2e4), (50.0, 5000.0))
         + WhiteKernel(sigma**2, (1e-8, 1.0)))
    gp = GaussianProcessRegressor(k, normalize_y=True, n_restarts_optimizer=2, random_state=0)
    t0 = time.perf_counter()
    gp.fit(X[idx].reshape(-1, 1), vals)
    mean, std = gp.predict(X.reshape(-1, 1), return_std=True)
    # std includes the white kernel (a new noisy reading); the curve's u is without it.
    noise_var = gp.kernel_.k2.noise_level * (gp._y_train_std**2 if gp.normalize_y else 1.0)
    u = np.sqrt(np.maximum(std**2 - noise_var, 1e-18))
    return mean, u, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--csmetro", default="target/release/csmetro")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--m", type=int, default=600)
    ap.add_argument("--noise-um", type=float, default=0.02)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--json", help="write every row here")
    ap.add_argument("--no-gp", action="store_true",
                    help="csmetro alone (the GP's figures do not depend on it: same samples)")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for fam in a.families.split(","):
            for seed in range(a.seeds):
                truth = curve(fam, seed)
                r = np.random.default_rng(77 + seed)
                idx = np.sort(r.choice(N, a.m, replace=False))
                vals = truth[idx] + r.normal(0, a.noise_um, a.m)
                cp, cu, ct, picked = run_csmetro(a.csmetro, idx, vals, a.noise_um, tmp)
                # Coverage at the sampled grid points and off them (the two regimes of the band).
                inside = np.abs(cp - truth) <= 2 * cu
                sampled = np.zeros(N, bool)
                sampled[idx] = True
                row = {"family": fam, "seed": seed, "m": a.m, "csmetro_method": picked,
                       "csmetro": {**figures(cp, cu, truth), "time_s": ct,
                                   "coverage_at_samples": float(inside[sampled].mean()),
                                   "coverage_off_samples": float(inside[~sampled].mean())}}
                line = (f"{fam:7s} seed {seed}: csmetro ({picked}) cover {row['csmetro']['coverage']:.3f} "
                        f"(samples {row['csmetro']['coverage_at_samples']:.3f}, off "
                        f"{row['csmetro']['coverage_off_samples']:.3f}) "
                        f"sharp {row['csmetro']['sharpness']:.2f} err {row['csmetro']['mean_abs_error_um']:.4f} "
                        f"{ct*1e3:.0f} ms")
                if not a.no_gp:
                    gm, gu, gt = run_gp(idx, vals, a.noise_um)
                    row["gp"] = {**figures(gm, gu, truth), "time_s": gt}
                    line += (f" | GP cover {row['gp']['coverage']:.3f} sharp {row['gp']['sharpness']:.2f} "
                             f"err {row['gp']['mean_abs_error_um']:.4f} {gt*1e3:.0f} ms")
                rows.append(row)
                print(line, flush=True)
    for who in ("csmetro",) if a.no_gp else ("csmetro", "gp"):
        v = [r[who] for r in rows]
        mean_u = [x["sharpness"] * x["mean_abs_error_um"] / 2 for x in v]
        print(f"{who:8s}: coverage mean {np.mean([x['coverage'] for x in v]):.3f} "
              f"min {np.min([x['coverage'] for x in v]):.3f}, sharpness mean "
              f"{np.mean([x['sharpness'] for x in v]):.2f}, mean u {np.mean(mean_u):.4f} µm, "
              f"mean |error| {np.mean([x['mean_abs_error_um'] for x in v]):.4f} µm, "
              f"median time {np.median([x['time_s'] for x in v])*1e3:.0f} ms")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
