#!/usr/bin/env python3
"""csmetro's pointwise band on a fourth set of curve shapes, written after the step-gap band was set.

tests/gp/band_variants.py (the third generator) was used to develop the band's step gaps in
session 40, so it no longer judges them. This one was written after that change and run once
for the figures in BENCHMARKS.md (numpy's PCG64, its own seeds): an unequal staircase, a
triangle wave (kinks, no steps), a clipped sine (flat tops), a stick-slip sawtooth with random
tooth heights and lengths (no period), spikes narrower than the sample spacing, a random
piecewise-linear curve, a sine with a backlash-like offset switching at random reversals, and a
short-period sine under a slow amplitude envelope. Each curve is sampled at m random grid points
of 0:5:9500 µm with Gaussian noise σ and reconstructed by
`csmetro reconstruct --method auto --noise-um σ`.

Figures per family and m, over the seeds: coverage = share of the grid with |curve − truth| ≤ 2u
(mean and lowest), sharpness = mean(2u) / mean |curve − truth| (mean). Usage:

    cargo build --release
    python3 tests/gp/band_fourth.py --csmetro target/release/csmetro --seeds 5 [--json F]
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from band_variants import N, SPAN, X, bumps, main, runner  # noqa: E402

FAMILIES = ["stair", "triangle", "clipped", "stickslip", "spikes", "kinks", "reversal", "envelope"]


def curve(family, r):
    """A truth on the grid (µm)."""
    if family == "stair":
        y = np.zeros(N)
        for at in r.uniform(0, SPAN, r.integers(10, 30)):
            y += r.normal(0, 0.2) * (X > at)
        return y + r.uniform(-1e-4, 1e-4) * X
    if family == "triangle":
        p = r.uniform(200, 800)
        t = (X / p + r.uniform()) % 1.0
        return r.uniform(0.3, 1.0) * (2 * np.abs(2 * t - 1) - 1)
    if family == "clipped":
        a = r.uniform(0.4, 1.0)
        s = a * np.sin(2 * np.pi * X / r.uniform(300, 1000) + r.uniform(0, 6))
        return np.clip(s, -0.6 * a, 0.6 * a)
    if family == "stickslip":
        y, x0 = np.zeros(N), 0.0
        while x0 < SPAN:
            length, height = r.uniform(100, 500), r.uniform(0.1, 0.6)
            inside = (X >= x0) & (X < x0 + length)
            y[inside] = height * ((X[inside] - x0) / length - 0.5)
            x0 += length
        return y
    if family == "spikes":
        return bumps(0.4 * np.sin(2 * np.pi * X / r.uniform(400, 1200)), r, 12, (5, 10), (0.1, 0.4))
    if family == "kinks":
        knots = np.sort(np.concatenate([[0, SPAN], r.uniform(0, SPAN, 15)]))
        return np.interp(X, knots, r.normal(0, 0.4, knots.size))
    if family == "reversal":
        y = 0.5 * np.sin(2 * np.pi * X / r.uniform(500, 1500))
        off = np.full(N, r.uniform(0.05, 0.3))
        for c in np.sort(r.uniform(0, SPAN, 6)):
            off[X > c] *= -1
        return y + off
    if family == "envelope":
        env = 0.3 + 0.25 * np.sin(2 * np.pi * X / r.uniform(3000, 8000) + r.uniform(0, 6))
        return env * np.sin(2 * np.pi * X / r.uniform(100, 300) + r.uniform(0, 6))
    raise ValueError(family)


SEEDS = (7919, 101)

if __name__ == "__main__":
    sys.exit(main(FAMILIES, runner(curve, FAMILIES, *SEEDS), __doc__))
