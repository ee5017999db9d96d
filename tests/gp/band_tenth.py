#!/usr/bin/env python3
"""csmetro's pointwise band on a tenth set of curve shapes, written at the end of session 44.

The ninth generator (tests/gp/band_ninth.py) judged session 44's two changes and has been seen.
This one was written and committed at the end of session 44, before any later change to the
band, and not run: the next change is judged on it first, once (numpy's PCG64, its own seeds).
Its shapes aim at what session 44 found weakest or widest: Gaussian spikes of 5–15 µm on a cycle
(narrower than the samples' spacing at m = 100), a long cycle of half the noise, ringing that
decays after a step at a random place, a 20 µm sawtooth of the noise's size (a sub-spacing
periodic error) on a cycle, Lorentzian defects, two tones at a 1 : 3 ratio, a pure tilt under a
small cycle, and a cycle whose amplitude is modulated by a slow random walk. Each curve is
sampled at m random grid points of 0:5:9500 µm with Gaussian noise σ and reconstructed by
`csmetro reconstruct --method auto --noise-um σ`.

Figures per family and m, over the seeds: coverage = share of the grid with |curve − truth| ≤ 2u
(mean and lowest), sharpness = mean(2u) / mean |curve − truth| (mean), interval score in the
JSON. Usage:

    cargo build --release
    python3 tests/gp/band_tenth.py --csmetro target/release/csmetro --seeds 5 [--json F]
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from band_variants import N, SPAN, X, main, runner  # noqa: E402

# The draws' seeding (band_variants.seeded): per seed, per family.
SEEDS = (67867967, 401)

FAMILIES = [
    "spikes2",
    "halflong",
    "ringing",
    "finesaw",
    "lorentz",
    "twotone",
    "tilt2",
    "amwalk",
]


def cycle(r, period, amp):
    return amp * np.sin(2 * np.pi * X / period + r.uniform(0, 2 * np.pi))


def curve(family, r):
    """A truth on the grid (µm)."""
    if family == "spikes2":
        y = cycle(r, r.uniform(300, 900), 0.1)
        for at in r.uniform(0, SPAN, r.integers(3, 8)):
            width = r.uniform(5, 15)
            y += r.choice([-1, 1]) * r.uniform(0.05, 0.2) * np.exp(-0.5 * ((X - at) / width) ** 2)
        return y
    if family == "halflong":
        return cycle(r, r.uniform(2000, 4000), 0.005)
    if family == "ringing":
        at = r.uniform(0.2, 0.8) * SPAN
        after = X >= at
        tau, period = r.uniform(200, 800), r.uniform(100, 300)
        ring = np.where(after, np.exp(-(X - at) / tau) * np.cos(2 * np.pi * (X - at) / period), 0.0)
        return r.uniform(0.05, 0.2) * ring + cycle(r, r.uniform(500, 1200), 0.05)
    if family == "finesaw":
        saw = ((X + r.uniform(0, 20)) / 20.0) % 1.0 - 0.5
        return 0.02 * saw + cycle(r, r.uniform(300, 900), 0.1)
    if family == "lorentz":
        y = np.zeros(N)
        for at in r.uniform(0, SPAN, r.integers(2, 6)):
            w = r.uniform(20, 120)
            y += r.normal(0, 0.1) / (1 + ((X - at) / w) ** 2)
        return y
    if family == "twotone":
        p = r.uniform(400, 1200)
        return cycle(r, p, 0.2) + cycle(r, p / 3, r.uniform(0.02, 0.08))
    if family == "tilt2":
        return r.uniform(-0.3, 0.3) * (X / SPAN - 0.5) + cycle(r, r.uniform(200, 600), 0.015)
    if family == "amwalk":
        walk = np.cumsum(r.normal(0, 1, N))
        walk = (walk - walk.min()) / (walk.max() - walk.min() + 1e-12)
        phase = 2 * np.pi * X / r.uniform(300, 800) + r.uniform(0, 6.3)
        return (0.05 + 0.25 * walk) * np.sin(phase)
    raise ValueError(family)


if __name__ == "__main__":
    sys.exit(main(FAMILIES, runner(curve, FAMILIES, *SEEDS), __doc__))
