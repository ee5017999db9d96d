#!/usr/bin/env python3
"""csmetro's pointwise band on an eighth set of curve shapes, written for the change after session 43.

The seventh generator (tests/gp/band_seventh.py) judged session 43's change and was then run on
a dropped variant as well, so it has been seen. This one was written and committed at the end
of session 43, before any later change to the band, and not run: the next change to the band
is judged on it first, once (numpy's PCG64, its own seeds). Its shapes aim at what session 43
found weakest, peaky errors under the noise at small m, beside shapes a model fits: a cycle
with a flat-topped (clipped at a random level) crest, a sine of a third of the noise, a cycle
of three times the noise with one narrow dip, a cycle whose period drifts linearly (a chirp), a
sum of two close periods (a slow beat), an exponential end effect at a random end, a staircase
of 4–8 small steps smoothed over 20–60 µm, and a cycle plus a bias that lives on one fifth of
the travel. Each curve is sampled at m random grid points of 0:5:9500 µm with Gaussian noise σ
and reconstructed by `csmetro reconstruct --method auto --noise-um σ`.

Figures per family and m, over the seeds: coverage = share of the grid with |curve − truth| ≤ 2u
(mean and lowest), sharpness = mean(2u) / mean |curve − truth| (mean). Usage:

    cargo build --release
    python3 tests/gp/band_eighth.py --csmetro target/release/csmetro --seeds 5 [--json F]
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from band_variants import N, SPAN, X, main, runner  # noqa: E402

FAMILIES = ["flattop", "third", "dip", "chirp", "beat2", "endeffect", "smallsteps", "fifth"]


def cycle(r, period, amp):
    return amp * np.sin(2 * np.pi * X / period + r.uniform(0, 2 * np.pi))


def curve(family, r):
    """A truth on the grid (µm)."""
    if family == "flattop":
        y = cycle(r, r.uniform(300, 900), r.uniform(0.2, 0.8))
        level = r.uniform(0.4, 0.8) * np.abs(y).max()
        return np.clip(y, -np.inf, level)
    if family == "third":
        return cycle(r, r.uniform(200, 1500), 0.01 / 3)
    if family == "dip":
        at = r.uniform(500, SPAN - 500)
        return cycle(r, r.uniform(250, 800), 0.03) - r.uniform(0.02, 0.08) * np.exp(
            -(((X - at) / r.uniform(15, 40)) ** 2)
        )
    if family == "chirp":
        p0, p1 = r.uniform(250, 500), r.uniform(500, 1000)
        period = p0 + (p1 - p0) * X / SPAN
        phase = 2 * np.pi * np.cumsum(1.0 / period) * (SPAN / (N - 1))
        return r.uniform(0.2, 0.6) * np.sin(phase + r.uniform(0, 2 * np.pi))
    if family == "beat2":
        p = r.uniform(300, 600)
        return cycle(r, p, 0.3) + cycle(r, p * r.uniform(1.03, 1.08), 0.3)
    if family == "endeffect":
        tau = r.uniform(150, 600)
        d = X if r.uniform() < 0.5 else SPAN - X
        return r.uniform(0.1, 0.5) * np.exp(-d / tau) + cycle(r, r.uniform(300, 800), 0.05)
    if family == "smallsteps":
        y = np.zeros(N)
        for a in r.uniform(300, SPAN - 300, r.integers(4, 9)):
            y += r.normal(0, 0.05) * 0.5 * (1 + np.tanh((X - a) / (2 * r.uniform(5, 15))))
        return y
    if family == "fifth":
        start = r.uniform(0, SPAN * 0.8)
        inside = (X >= start) & (X < start + SPAN / 5)
        return cycle(r, r.uniform(300, 900), 0.2) + np.where(
            inside, r.uniform(0.01, 0.03) * np.sin(2 * np.pi * (X - start) / (SPAN / 5)), 0.0
        )
    raise ValueError(family)


if __name__ == "__main__":
    sys.exit(main(FAMILIES, runner(curve, FAMILIES, 32452843, 211), __doc__))
