"""The figures a characterisation reports, flattened from its ``summary.json``.

One table says what each figure is, its units and where it comes from; the device builds its
signals from it and the README lists it. Figures a campaign does not produce (R without repeated
approaches, anything "vs full" without a full scan, "vs truth" outside the simulator) are NaN.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Optional


class Figure(NamedTuple):
    attr: str
    units: str
    doc: str
    dtype: type = float


#: Per characterised axis (``x``, ``y``): the device's ``x.<attr>`` / ``y.<attr>`` signals.
AXIS_FIGURES: tuple[Figure, ...] = (
    Figure("iso_a", "µm", "ISO 230-2 A: bidirectional accuracy of positioning"),
    Figure("iso_e", "µm", "ISO 230-2 E: bidirectional systematic positional deviation"),
    Figure("iso_b", "µm", "ISO 230-2 B: reversal value (largest |x̄↑ - x̄↓|)"),
    Figure("iso_m", "µm", "ISO 230-2 M: mean bidirectional positional deviation"),
    Figure("iso_r", "µm", "ISO 230-2 R: bidirectional repeatability (NaN without repeated approaches)"),
    Figure(
        "iso_source",
        "",
        "what the ISO figures come from: full_scan, measured (repeated cycles) or reconstructed",
        str,
    ),
    Figure("measurements", "", "compressive-sensing measurements on this axis (both directions)", int),
    Figure("full_measurements", "", "full-scan measurements on this axis (0 without a full scan)", int),
    Figure("cv_error", "µm", "largest cross-validated recovery error estimate of the axis's components"),
    Figure("error_vs_full_mean", "µm", "mean |CS - full scan|, averaged over the axis's components (NaN without a full scan)"),
    Figure("error_vs_full_max", "µm", "largest |CS - full scan| of the axis's components (NaN without a full scan)"),
    Figure("error_vs_truth_mean", "µm", "mean |CS - truth|, averaged over the axis's components (simulator only)"),
    Figure("error_vs_truth_max", "µm", "largest |CS - truth| of the axis's components (simulator only)"),
    Figure("acquisition_time", "s", "physical acquisition time of the CS measurements"),
    Figure("time_saved", "%", "acquisition time saved against the full scan (NaN without a full scan)"),
)

#: For the whole campaign: the device's own signals.
CAMPAIGN_FIGURES: tuple[Figure, ...] = (
    Figure("measurements", "", "CS measurements, all axes", int),
    Figure("acquisition_time", "s", "physical acquisition time of the CS measurements, all axes"),
    Figure("time_saved", "%", "acquisition time saved against the full scan (NaN without one)"),
    Figure("measurements_saved", "%", "measurements saved against the full scan (NaN without one)"),
)

NAN = float("nan")


def _num(v: Any, dtype: type = float):
    if dtype is str:
        return "" if v is None else str(v)
    if v is None:
        return 0 if dtype is int else NAN
    try:
        return dtype(v)
    except (TypeError, ValueError):
        return 0 if dtype is int else NAN


def _get(d: Any, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def unset(f: Figure) -> Any:
    """A figure's value before (or without) a result: NaN, 0 for counts, "" for names."""
    return _num(None, f.dtype)


def empty_axis() -> dict[str, Any]:
    """Every axis figure, unset."""
    return {f.attr: unset(f) for f in AXIS_FIGURES}


def empty_campaign() -> dict[str, Any]:
    """Every campaign figure, unset."""
    return {f.attr: unset(f) for f in CAMPAIGN_FIGURES}


def iso_block(iso_axis: Optional[dict]) -> tuple[str, Optional[dict]]:
    """The figures the service chose for an axis (``source``) and that source's name."""
    if not isinstance(iso_axis, dict):
        return "", None
    source = iso_axis.get("source")
    if isinstance(source, str) and isinstance(iso_axis.get(source), dict):
        return source, iso_axis[source]
    for s in ("full_scan", "measured", "reconstructed"):
        if isinstance(iso_axis.get(s), dict):
            return s, iso_axis[s]
    return "", None


def _agg(values: list[Optional[float]], how) -> float:
    vals = [float(v) for v in values if isinstance(v, (int, float)) and not math.isnan(v)]
    return how(vals) if vals else NAN


def axis_figures(summary: dict, axis: str, iso230: Optional[dict] = None) -> dict[str, Any]:
    """The figures of ``axis`` in a campaign's ``summary.json`` (``iso230``: the content of
    ``iso230.json``, used when the summary has no ``iso230`` key)."""
    out = empty_axis()
    iso_all = summary.get("iso230") if isinstance(summary.get("iso230"), dict) else iso230 or {}
    source, iso = iso_block(iso_all.get(axis))
    out["iso_source"] = source
    if iso:
        for letter in "aebmr":
            out[f"iso_{letter}"] = _num(iso.get(f"{letter}_um"))
    entry = next(
        (a for a in summary.get("axes") or [] if isinstance(a, dict) and a.get("axis") == axis), None
    )
    if entry is None:
        return out
    out["measurements"] = _num(_get(entry, "phases", "cs", "measurements"), int)
    out["full_measurements"] = _num(_get(entry, "phases", "full", "measurements"), int)
    out["acquisition_time"] = _num(_get(entry, "phases", "cs", "acquisition_s"))
    out["time_saved"] = _num(entry.get("acquisition_saved_pct"))
    comps = [c for c in entry.get("components") or [] if isinstance(c, dict)]
    out["cv_error"] = _agg([_get(c, "cs", "cv_error_um") for c in comps], max)
    for ref in ("full", "truth"):
        out[f"error_vs_{ref}_mean"] = _agg(
            [_get(c, f"cs_vs_{ref}", "mean_abs_um") for c in comps], lambda v: sum(v) / len(v)
        )
        out[f"error_vs_{ref}_max"] = _agg([_get(c, f"cs_vs_{ref}", "max_abs_um") for c in comps], max)
    return out


def campaign_figures(summary: dict) -> dict[str, Any]:
    """The whole campaign's figures in ``summary.json``."""
    total = summary.get("total") or {}
    return {
        "measurements": _num(_get(total, "cs", "measurements"), int),
        "acquisition_time": _num(_get(total, "cs", "acquisition_s")),
        "time_saved": _num(total.get("acquisition_saved_pct")),
        "measurements_saved": _num(total.get("measurements_saved_pct")),
    }
