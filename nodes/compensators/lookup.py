"""``compensator.lookup``: piecewise-linear depth correction over binned distance.

The training placements are binned by measured depth; each bin with enough
placements gives one knot (mean measured z, mean z error). A measurement is
corrected by linear interpolation between the knots (held constant beyond the
first and last knot, and flagged as extrapolated there). No functional form is
assumed, so it also follows errors a polynomial would not, at the price of
needing placements in every bin.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from nodes.contracts.compensator import fit_compensator
from nodes.contracts.compensator._common import (
    RayFitParams,
    Samples,
    along_ray,
    resolve_along_ray,
)
from stereograph.api import Field, NodeError

__all__ = ["fit_lookup", "lookup", "predict_lookup"]

INPUTS = ("z_cm",)


def fit_lookup(
    samples: Samples,
    n_bins: int = 6,
    bin_edges_cm: list[float] | None = None,
    min_per_bin: int = 3,
    xy: str = "auto",
) -> dict[str, Any]:
    """Knots of a piecewise-linear z correction, cm.

    Parameters
    ----------
    samples : Samples
        Training placements with truth.
    n_bins : int
        Equal-width bins over the training range of measured z (ignored when
        ``bin_edges_cm`` is given).
    bin_edges_cm : list of float, optional
        Explicit increasing bin edges of measured z, cm.
    min_per_bin : int
        Bins with fewer placements give no knot.
    xy : {"auto", "along_ray", "keep"}
        What the correction does to x, y (see :func:`resolve_along_ray`).

    Returns
    -------
    dict
        ``{"knots_z_cm": [...], "knots_correction_cm": [...], "knots_n": [...], "edges_cm": [...],
        "along_ray"}``.
    """
    z = samples.xyz_cm[:, 2]
    err = samples.truth_cm[:, 2] - z
    if bin_edges_cm is not None:
        edges = np.asarray(bin_edges_cm, dtype=float)
        if edges.ndim != 1 or len(edges) < 3 or np.any(np.diff(edges) <= 0):
            raise NodeError(
                f"bin_edges_cm must be at least 3 increasing values (cm), got {list(bin_edges_cm)}."
            )
    else:
        edges = np.linspace(float(np.min(z)), float(np.max(z)), n_bins + 1)
    # Bin i holds edges[i] <= z < edges[i+1]; the last bin also takes its right edge.
    which = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, len(edges) - 2)
    inside = (z >= edges[0]) & (z <= edges[-1])
    knots_z, knots_c, knots_n = [], [], []
    for i in range(len(edges) - 1):
        sel = inside & (which == i)
        if np.count_nonzero(sel) >= min_per_bin:
            knots_z.append(float(np.mean(z[sel])))
            knots_c.append(float(np.mean(err[sel])))
            knots_n.append(int(np.count_nonzero(sel)))
    if len(knots_z) < 2:
        raise NodeError(
            f"only {len(knots_z)} of {len(edges) - 1} distance bins hold at least "
            f"{min_per_bin} training placements; "
            "a piecewise-linear correction needs 2 knots."
        )
    z_new = z + np.interp(z, knots_z, knots_c)
    return {
        "knots_z_cm": knots_z,
        "knots_correction_cm": knots_c,
        "knots_n": knots_n,
        "edges_cm": [float(e) for e in edges],
        "along_ray": resolve_along_ray(xy, samples, z_new),
    }


def predict_lookup(coefficients: Mapping[str, Any], samples: Samples) -> np.ndarray:
    """Corrected positions, cm (N, 3), from a :func:`fit_lookup` model."""
    z = samples.xyz_cm[:, 2]
    z_new = z + np.interp(z, coefficients["knots_z_cm"], coefficients["knots_correction_cm"])
    return along_ray(samples.xyz_cm, z_new, samples.frame, coefficients.get("along_ray", True))


def _only_where_bins_hold_data(
    model: dict[str, Any], samples: Samples, min_per_bin: int, ctx=None
) -> None:
    """The table holds only where its bins had ``min_per_bin`` placements: narrow ``valid_range`` to
    the placements of those bins (outside, ``compensator.apply`` flags the result as extrapolated),
    and say how many placements and bins the table could not use."""
    c = model["coefficients"]
    edges = np.asarray(c["edges_cm"], float)
    z = samples.xyz_cm[:, 2]
    which = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, len(edges) - 2)
    counts = np.bincount(which[(z >= edges[0]) & (z <= edges[-1])], minlength=len(edges) - 1)
    used = (
        np.isin(which, np.flatnonzero(counts >= min_per_bin)) & (z >= edges[0]) & (z <= edges[-1])
    )
    if np.any(used):
        model["valid_range"]["z_cm"] = {
            "min": float(np.min(z[used])),
            "max": float(np.max(z[used])),
        }
    n_bins, n_kept = len(edges) - 1, len(c["knots_z_cm"])
    if n_kept < n_bins and ctx is not None:
        ctx.warn(
            f"only {n_kept} of {n_bins} distance bins hold at least {min_per_bin} "
            "training placements: the table "
            f"uses {int(np.count_nonzero(used))} of {len(z)} placements, and holds over measured z "
            f"{model['valid_range']['z_cm']['min']:.3g}-"
            f"{model['valid_range']['z_cm']['max']:.3g} cm only; "
            "fewer bins (n_bins) or more placements would use them all"
        )


class LookupParams(RayFitParams):
    """Options of ``compensator.lookup``."""

    n_bins: int = Field(
        6,
        ge=2,
        le=100,
        description="Equal-width bins of measured z over the training range (count).",
    )
    bin_edges_cm: list[float] | None = Field(
        None, description="Explicit increasing bin edges of measured z (cm); overrides n_bins."
    )
    min_per_bin: int = Field(
        3, ge=1, description="Fewest training placements a bin needs to give a knot (count)."
    )


def _title(params: LookupParams, model: dict) -> str:
    c = model["coefficients"]
    width = np.diff(c["edges_cm"])
    widths = (
        f"{np.min(width):.3g}"
        if np.ptp(width) < 1e-3 * np.max(width)
        else f"{np.min(width):.3g}-{np.max(width):.3g}"
    )
    return (
        f"z correction = piecewise linear through {len(c['knots_z_cm'])} knots (bin "
        f"means; bins {widths} cm "
        f"wide, at least {params.min_per_bin} placements)"
    )


@fit_compensator(
    "compensator.lookup",
    params=LookupParams,
    predict=predict_lookup,
    inputs=INPUTS,
    min_points=lambda p: 2 * p.min_per_bin,
    span="z",
    axes=("z",),
    title=_title,
    version="3",
    after=lambda p, model, samples, ctx: _only_where_bins_hold_data(
        model, samples, p.min_per_bin, ctx
    ),
    model="Knots of a z correction table (cm).",
    figure="z error (truth - measured, cm) vs measured z: placements, fitted table, valid range.",
)
def lookup(params: LookupParams, samples: Samples) -> dict[str, Any]:
    """Fit a piecewise-linear z correction over binned measured distance on the training
    placements."""
    return fit_lookup(samples, params.n_bins, params.bin_edges_cm, params.min_per_bin, params.xy)
