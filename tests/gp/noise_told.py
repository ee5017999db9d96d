#!/usr/bin/env python3
"""csmetro's band when the noise σ told is not the samples' own: coverage at the sample points
and off them.

The band at a sample point rests on the σ told (`--noise-um`): a curve through its samples is
off by the sample's own noise there, and the band takes σ for it. This script samples the
families of the third to fifth generators (tests/gp/band_variants.py, band_fourth.py,
band_fifth.py; their own seeds) with Gaussian noise σ = 0.01 µm and reconstructs them telling
σ × `--told` instead, then prints the share of grid points with |curve − truth| ≤ 2u at the
sample points, off them, and over all, and the sharpness mean(2u) / mean |curve − truth| (mean
and median of the curves). `--sigma 0 --told-um 0.01` samples the curves exactly and tells
0.01 µm. Usage:

    cargo build --release
    python3 tests/gp/noise_told.py --csmetro target/release/csmetro --m 300 --told 0.5
"""
import argparse
import importlib
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import band_variants as bv  # noqa: E402

GENERATORS = ["band_variants", "band_fourth", "band_fifth"]
SIGMA = 0.01


def main():
    a = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    a.add_argument("--csmetro", default="target/release/csmetro")
    a.add_argument("--m", type=int, default=300)
    a.add_argument("--told", type=float, default=0.5, help="σ told over the samples' σ")
    a.add_argument("--seeds", type=int, default=5)
    a.add_argument("--sigma", type=float, default=SIGMA, help="the samples' σ, µm")
    a.add_argument("--told-um", type=float, help="σ told, µm (instead of --told)")
    a.add_argument("--generators", nargs="+", default=GENERATORS, help="tests/gp modules")
    args = a.parse_args()
    told = args.told_um if args.told_um is not None else args.sigma * args.told
    hit_at, hit_off, sharp = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.generators:
            gen = importlib.import_module(name)
            for family in gen.FAMILIES:
                for seed in range(args.seeds):
                    r = bv.seeded(gen.FAMILIES, *gen.SEEDS, family, args.m, seed)
                    truth = gen.curve(family, r)
                    idx, y = bv.sample(truth, r, args.m, args.sigma)
                    g, u = bv.reconstruct(args.csmetro, idx, y, told, tmp)
                    hit = np.abs(g - truth) <= 2 * u
                    sharp.append(np.mean(2 * u) / max(np.mean(np.abs(g - truth)), 1e-300))
                    at = np.zeros(bv.N, bool)
                    at[idx] = True
                    hit_at.append(hit[at])
                    hit_off.append(hit[~at])
    at, off = np.concatenate(hit_at), np.concatenate(hit_off)
    print(
        f"m = {args.m}, samples' σ {args.sigma} µm, told {told:g} µm: coverage at the samples "
        f"{at.mean():.3f}, off them {off.mean():.3f}, all {np.concatenate([at, off]).mean():.3f}; "
        f"sharpness mean {np.mean(sharp):.3g}, median {np.median(sharp):.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
