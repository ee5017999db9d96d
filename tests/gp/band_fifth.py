#!/usr/bin/env python3
"""csmetro's pointwise band on a fifth set of curve shapes, written before session 41's change.

The third generator (tests/gp/band_variants.py) shaped the band's step gaps in session 40 and
the fourth (tests/gp/band_fourth.py) showed where its noise subtraction fails (a curve error
at or below the sensor noise); session 41 worked on that with the fourth in view, so neither
judges it. This one was written at the start of session 41, before that change, and is run
once for the figures in BENCHMARKS.md (numpy's PCG64, its own seeds): two incommensurate
periods (a leadscrew and its thread), a thermal exponential drift under a period, a rough
curve with a 1/f spectrum, tanh-rounded steps, an amplitude- and frequency-modulated cycle, a
cubic bow with a small period, a sine below the noise (half its σ) and a cluster of narrow sinc
defects. Each curve is sampled at m random grid points of 0:5:9500 µm with Gaussian noise σ and
reconstructed by `csmetro reconstruct --method auto --noise-um σ`.

Figures per family and m, over the seeds: coverage = share of the grid with |curve − truth| ≤ 2u
(mean and lowest), sharpness = mean(2u) / mean |curve − truth| (mean). Usage:

    cargo build --release
    python3 tests/gp/band_fifth.py --csmetro target/release/csmetro --seeds 5 [--json F]
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from band_variants import N, SPAN, X, main, runner  # noqa: E402

FAMILIES = ["twoperiod", "thermal", "pink", "rounded", "amfm", "bow", "faint", "sinc"]


def curve(family, r):
    """A truth on the grid (µm)."""
    if family == "twoperiod":
        lead, thread = r.uniform(800, 1500), r.uniform(150, 350)
        return r.uniform(0.3, 1.0) * np.sin(2 * np.pi * X / lead + r.uniform(0, 6)) + r.uniform(
            0.05, 0.3
        ) * np.sin(2 * np.pi * X / thread + r.uniform(0, 6))
    if family == "thermal":
        tau = r.uniform(1000, 4000)
        return r.uniform(0.5, 2.0) * (1 - np.exp(-X / tau)) + 0.2 * np.sin(
            2 * np.pi * X / r.uniform(300, 800)
        )
    if family == "pink":
        f = np.fft.rfftfreq(N, d=SPAN / (N - 1))
        amp = np.zeros(f.size)
        amp[1:] = 1.0 / f[1:]
        spec = amp * np.exp(2j * np.pi * r.uniform(size=f.size)) * r.rayleigh(size=f.size)
        y = np.fft.irfft(spec, n=N)
        return 0.5 * y / np.std(y)
    if family == "rounded":
        y = np.zeros(N)
        for at in r.uniform(0, SPAN, r.integers(5, 15)):
            y += r.normal(0, 0.3) * np.tanh((X - at) / r.uniform(5, 40))
        return y
    if family == "amfm":
        p0 = r.uniform(300, 600)
        phase = 2 * np.pi * (X / p0 + 0.2 * np.sin(2 * np.pi * X / r.uniform(4000, 9000)))
        return (0.4 + 0.3 * np.cos(2 * np.pi * X / r.uniform(2000, 6000))) * np.sin(phase)
    if family == "bow":
        t = X / SPAN - 0.5
        c = r.normal(0, 1.0, 3)
        return c[0] * t + c[1] * t**2 + 2 * c[2] * t**3 + 0.05 * np.sin(
            2 * np.pi * X / r.uniform(200, 500)
        )
    if family == "faint":
        return 0.005 * np.sin(2 * np.pi * X / r.uniform(300, 1200) + r.uniform(0, 6))
    if family == "sinc":
        y = 0.3 * np.sin(2 * np.pi * X / r.uniform(600, 1400))
        centre = r.uniform(1500, SPAN - 1500)
        for at in centre + r.uniform(-800, 800, 5):
            y += r.uniform(0.1, 0.4) * np.sinc((X - at) / r.uniform(8, 25))
        return y
    raise ValueError(family)


SEEDS = (104729, 977)

if __name__ == "__main__":
    sys.exit(main(FAMILIES, runner(curve, FAMILIES, *SEEDS), __doc__))
