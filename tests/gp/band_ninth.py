#!/usr/bin/env python3
"""csmetro's pointwise band on a ninth set of curve shapes, written to judge session 44's change.

The eighth generator (tests/gp/band_eighth.py) judged a first version of session 44's change
(the band's local scale applied before the noise is taken out) and has been seen. This one was
written after that, before the final version ran on it, and is run once on it and on the band
before it (numpy's PCG64, its own seeds). Its shapes are new to the generators: a rectified
sine (a cusp at every zero), an S-curve (tanh) of random width under a small cycle, a cycle with
a short burst of a period below the samples' spacing at m = 100, five Gaussian bumps of random
width, a smoothed asymmetric sawtooth, a period that switches at a random place (phase
continuous), a bow under a sine of half the noise, and a Brownian path (non-stationary
roughness). Each curve is sampled at m random grid points of 0:5:9500 µm with Gaussian noise σ
and reconstructed by `csmetro reconstruct --method auto --noise-um σ`.

Figures per family and m, over the seeds: coverage = share of the grid with |curve − truth| ≤ 2u
(mean and lowest), sharpness = mean(2u) / mean |curve − truth| (mean), interval score in the
JSON. Usage:

    cargo build --release
    python3 tests/gp/band_ninth.py --csmetro target/release/csmetro --seeds 5 [--json F]
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from band_variants import N, SPAN, X, main, runner  # noqa: E402

FAMILIES = [
    "rectified",
    "scurve",
    "burst",
    "bumps5",
    "skewsaw",
    "periodswitch",
    "microbow",
    "brownian",
]


def cycle(r, period, amp):
    return amp * np.sin(2 * np.pi * X / period + r.uniform(0, 2 * np.pi))


def smooth(y, width_um):
    """y convolved with a box of `width_um` (edges padded with their values)."""
    k = max(1, int(round(width_um / (SPAN / (N - 1)))))
    pad = np.pad(y, k, mode="edge")
    return np.convolve(pad, np.ones(k) / k, mode="same")[k:-k]


def curve(family, r):
    """A truth on the grid (µm)."""
    if family == "rectified":
        y = r.uniform(0.1, 0.4) * np.abs(np.sin(np.pi * X / r.uniform(300, 900) + r.uniform(0, 3)))
        return y - y.mean()
    if family == "scurve":
        at, width = r.uniform(0.2, 0.8) * SPAN, r.uniform(100, 600)
        step = r.uniform(0.05, 0.3) * np.tanh((X - at) / width)
        return step + cycle(r, r.uniform(200, 700), 0.03)
    if family == "burst":
        at, length = r.uniform(500, SPAN - 1000), r.uniform(200, 500)
        inside = (X >= at) & (X < at + length)
        fast = r.uniform(0.02, 0.05) * np.sin(2 * np.pi * (X - at) / r.uniform(40, 80))
        return cycle(r, r.uniform(400, 900), 0.1) + np.where(inside, fast, 0.0)
    if family == "bumps5":
        y = np.zeros(N)
        for _ in range(5):
            at, w = r.uniform(0, SPAN), r.uniform(50, 500)
            y += r.normal(0, 0.05) * np.exp(-0.5 * ((X - at) / w) ** 2)
        return y
    if family == "skewsaw":
        period, rise = r.uniform(400, 1200), r.uniform(0.7, 0.9)
        t = ((X + r.uniform(0, period)) / period) % 1.0
        saw = np.where(t < rise, t / rise, (1.0 - t) / (1.0 - rise))
        return r.uniform(0.1, 0.3) * (smooth(saw, 20.0) - 0.5)
    if family == "periodswitch":
        at, p1, p2 = r.uniform(0.3, 0.7) * SPAN, r.uniform(200, 500), r.uniform(500, 1000)
        period = np.where(X < at, p1, p2)
        phase = 2 * np.pi * np.cumsum(1.0 / period) * (SPAN / (N - 1))
        return 0.2 * np.sin(phase + r.uniform(0, 2 * np.pi))
    if family == "microbow":
        u = X / SPAN - 0.5
        return r.uniform(0.02, 0.05) * (4 * u * u - 1 / 3) + cycle(r, r.uniform(200, 1200), 0.005)
    if family == "brownian":
        y = np.cumsum(r.normal(0, 1, N))
        y -= np.linspace(y[0], y[-1], N) * r.uniform(0, 1)
        return 0.05 * (y - y.mean()) / y.std()
    raise ValueError(family)


if __name__ == "__main__":
    sys.exit(main(FAMILIES, runner(curve, FAMILIES, 49979687, 307), __doc__))
