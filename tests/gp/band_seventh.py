#!/usr/bin/env python3
"""csmetro's pointwise band on a seventh set of curve shapes, written to judge session 43's change.

Session 43 changed how the band's local scale is shrunk (an empirical-Bayes prior weight in
place of a fixed one) with the third to sixth generators in view, so they no longer judge it.
This one was written after that change and before either band was run on it, and run once on
both (session 42's and session 43's) for the figures in BENCHMARKS.md (numpy's PCG64, its own
seeds): three incommensurate periods of random amplitudes, a cycle whose amplitude decays
along the travel, a square-root wear curve steepest at one end, plateaus joined by logistic
ramps 30–80 µm wide, narrow impulses (5–12 µm, below the spacing of the samples at every m)
on a cycle, an oscillating AR(2) roughness (a quasi-period that wanders), a tilt with a sine of
a quarter of the noise, and a cycle whose phase jumps once. Each curve is sampled at m random
grid points of 0:5:9500 µm with Gaussian noise σ and reconstructed by
`csmetro reconstruct --method auto --noise-um σ`.

Figures per family and m, over the seeds: coverage = share of the grid with |curve − truth| ≤ 2u
(mean and lowest), sharpness = mean(2u) / mean |curve − truth| (mean). Usage:

    cargo build --release
    python3 tests/gp/band_seventh.py --csmetro target/release/csmetro --seeds 5 [--json F]
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from band_variants import N, SPAN, X, main, runner  # noqa: E402

FAMILIES = ["three", "decay", "wear", "plateaus", "impulses", "ar2", "tilt", "phasejump"]


def cycle(r, period, amp):
    return amp * np.sin(2 * np.pi * X / period + r.uniform(0, 2 * np.pi))


def curve(family, r):
    """A truth on the grid (µm)."""
    if family == "three":
        return sum(cycle(r, r.uniform(lo, hi), r.uniform(0.05, 0.5)) for lo, hi in
                   ((150, 300), (400, 800), (1200, 3000)))
    if family == "decay":
        return np.exp(-X / r.uniform(1500, 5000)) * cycle(r, r.uniform(250, 700), r.uniform(0.3, 1))
    if family == "wear":
        t = X / SPAN if r.uniform() < 0.5 else 1 - X / SPAN
        return r.uniform(0.5, 2.0) * np.sqrt(t) + cycle(r, r.uniform(300, 900), 0.05)
    if family == "plateaus":
        k = r.integers(3, 7)
        at = np.sort(r.uniform(500, SPAN - 500, k))
        y = np.zeros(N)
        for a in at:
            y += r.normal(0, 0.3) / (1 + np.exp(-(X - a) / r.uniform(30, 80)))
        return y
    if family == "impulses":
        y = cycle(r, r.uniform(300, 900), 0.3)
        for a in r.uniform(200, SPAN - 200, r.integers(2, 6)):
            y += r.choice([-1, 1]) * r.uniform(0.1, 0.4) * np.exp(
                -(((X - a) / r.uniform(5, 12)) ** 2)
            )
        return y
    if family == "ar2":
        # Poles at radius ρ and angle 2π·step/period: roughness with a wandering quasi-period.
        rho, period = r.uniform(0.97, 0.995), r.uniform(200, 600)
        a1, a2 = 2 * rho * np.cos(2 * np.pi * (SPAN / (N - 1)) / period), -rho * rho
        y = np.zeros(N)
        for i in range(2, N):
            y[i] = a1 * y[i - 1] + a2 * y[i - 2] + r.normal()
        return 0.03 * y / y.std()
    if family == "tilt":
        return r.uniform(-1, 1) * X / SPAN + cycle(r, r.uniform(300, 1200), 0.0025)
    if family == "phasejump":
        at, p = r.uniform(2500, 7000), r.uniform(300, 800)
        jump = r.uniform(np.pi / 2, np.pi)
        phase = r.uniform(0, 2 * np.pi)
        return 0.4 * np.sin(2 * np.pi * X / p + phase + np.where(X < at, 0.0, jump))
    raise ValueError(family)


if __name__ == "__main__":
    sys.exit(main(FAMILIES, runner(curve, FAMILIES, 15485863, 331), __doc__))
