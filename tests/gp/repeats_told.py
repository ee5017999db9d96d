#!/usr/bin/env python3
"""csmetro's band when a samples file repeats each position and the σ told is too low.

An own curve (sin 400 µm + 0.2 cos 85 µm, µm) on the grid 0:5:4000, 150 random positions read
in 3 cycles, each reading with Gaussian noise σ = 0.02 µm (an averaged sample: 0.02/√3), written
in csmetro's samples layout and reconstructed with `--noise-um` told. Prints, per seed, the share
of the samples and of the other grid points with |curve − truth| ≤ 2u, the sharpness
mean(2u)/mean|curve − truth| and the mean |error| µm. Usage:

    cargo build --release
    python3 tests/gp/repeats_told.py --csmetro target/release/csmetro --told 0.002
"""
import argparse
import os
import subprocess
import tempfile

import numpy as np

N, STEP, M, CYCLES, SIGMA = 801, 5.0, 150, 3, 0.02
HEADER = (
    "seq,phase,axis,direction,cycle,target_x_um,target_y_um,meas_x_um,meas_y_um,theta_mrad,"
    "encoder_um,time_s,quality,frames,rejected,pass,run,target_um,position_um,error_um\n"
)


def truth(x):
    return np.sin(2 * np.pi * x / 400) + 0.2 * np.cos(2 * np.pi * x / 85)


def main():
    a = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    a.add_argument("--csmetro", default="target/release/csmetro")
    a.add_argument("--told", type=float, default=0.002, help="σ told, µm")
    a.add_argument("--seeds", type=int, default=3)
    args = a.parse_args()
    x = np.arange(N) * STEP
    with tempfile.TemporaryDirectory() as tmp:
        samples, out = os.path.join(tmp, "cycles.csv"), os.path.join(tmp, "curve.csv")
        for seed in range(1, args.seeds + 1):
            r = np.random.default_rng(seed)
            idx = r.choice(N, M, replace=False)
            rows = []
            for c in range(CYCLES):
                for i in idx:
                    p = x[i]
                    e = truth(p) + SIGMA * r.normal()
                    rows.append(
                        f"0,cs,x,forward,{c},{p},0,{p + e},0,0,{p},0,1,1,0,,{2 * c},{p},{p},{e}\n"
                    )
            with open(samples, "w") as f:
                f.write(HEADER + "".join(rows))
            subprocess.run(
                [args.csmetro, "reconstruct", "--grid", f"0:{STEP:g}:{(N - 1) * STEP:g}",
                 "--noise-um", str(args.told), "--samples", samples, "--out", out],
                check=True, capture_output=True,
            )
            d = np.loadtxt(out, delimiter=",", skiprows=1)
            err = np.abs(d[:, 1] - truth(d[:, 0]))
            hit = err <= 2 * d[:, 2]
            at = np.zeros(N, bool)
            at[idx] = True
            print(
                f"seed {seed}: at the samples {hit[at].mean():.3f}, off them "
                f"{hit[~at].mean():.3f}, sharpness {np.mean(2 * d[:, 2]) / err.mean():.2f}, "
                f"mean |error| {err.mean():.4f} µm"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
