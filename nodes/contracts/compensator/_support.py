"""Where a fitted compensation model is supported by its training placements.

A model's ``valid_range`` is a box over its input variables. For a one-variable
model (a correction of z as a function of z or of disparity) the box is the whole
story. A model of several variables (``compensator.xyz`` reads u, v and
disparity) is fitted to placements that usually lie on one surface -- balls on a
table -- which is a thin slab inside that box: off the slab the polynomial is
unconstrained, and measured on one fit it gave corrections of 27 cm inside the
box while its training residual was 0.007 cm. So a model also records

- the training placements' spread along their principal axes (raw x, y, z, cm),
  so that a measurement off their surface (a ball on a box, on a shelf) is
  flagged, with a margin derived from the spread itself; and
- the largest correction it applied in training, so that a correction far larger
  than any it was fitted on is flagged whatever the geometry.

``compensator.apply`` marks such a location ``extrapolated`` (and
``ik.pick_sequence`` refuses extrapolated targets by default).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["describe_support", "outside_support"]

# Off the training surface, a margin of this fraction of the placements' largest extent (and never
# less than 3 standard deviations of their spread across it): a ball a little off the table is
# still inside, one on a box is not.
SURFACE_MARGIN_FRACTION = 0.05
# A correction may exceed the largest one seen in training by this factor plus 3 training
# residuals before it is called unsupported.
CORRECTION_FACTOR = 1.5


def describe_support(
    raw_xyz_cm: np.ndarray, corrected_xyz_cm: np.ndarray, truth_xyz_cm: np.ndarray
) -> dict:
    """Summarise where the training placements lie and how large their corrections were.

    Parameters
    ----------
    raw_xyz_cm : (N, 3) array
        The training placements as measured (cm).
    corrected_xyz_cm : (N, 3) array
        The fitted model's corrected values at them (cm).
    truth_xyz_cm : (N, 3) array
        Their true positions (cm).

    Returns
    -------
    dict
        ``{"center_cm", "axes" (rows: principal directions), "min_cm", "max_cm", "margin_cm"
        (per principal axis, cm), "max_correction_cm", "residual_rms_cm"}`` -- plain lists and
        floats (JSON).
    """
    raw = np.asarray(raw_xyz_cm, dtype=float).reshape(-1, 3)
    center = raw.mean(axis=0)
    if len(raw) >= 3:
        _, _, axes = np.linalg.svd(raw - center, full_matrices=False)
    else:
        axes = np.eye(3)
    coords = (raw - center) @ axes.T
    lo, hi = coords.min(axis=0), coords.max(axis=0)
    extent = float(np.max(hi - lo)) if len(raw) else 0.0
    margin = np.maximum(3.0 * coords.std(axis=0), SURFACE_MARGIN_FRACTION * extent)
    correction = np.linalg.norm(
        np.asarray(corrected_xyz_cm, dtype=float).reshape(-1, 3) - raw, axis=1
    )
    residual = np.linalg.norm(
        np.asarray(corrected_xyz_cm, dtype=float).reshape(-1, 3)
        - np.asarray(truth_xyz_cm, dtype=float).reshape(-1, 3),
        axis=1,
    )
    return {
        "center_cm": center.tolist(),
        "axes": axes.tolist(),
        "min_cm": lo.tolist(),
        "max_cm": hi.tolist(),
        "margin_cm": margin.tolist(),
        "max_correction_cm": float(correction.max()) if len(correction) else 0.0,
        "residual_rms_cm": float(np.sqrt(np.mean(residual**2))) if len(residual) else 0.0,
    }


def outside_support(
    support: Mapping[str, Any] | None, n_inputs: int, raw_xyz_cm, corrected_xyz_cm
) -> list[str]:
    """Why a measurement lies where the model is not supported (empty: it is supported).

    Parameters
    ----------
    support : mapping or None
        :func:`describe_support`'s record (models fitted before it existed have none: no check).
    n_inputs : int
        How many input variables the model reads; the surface check applies from 2 on.
    raw_xyz_cm, corrected_xyz_cm : (3,) array
        The measurement and the model's correction of it (cm).

    Returns
    -------
    list of str
        Short human reasons, e.g. ``"2.4 cm off the training placements' surface (margin 1.0 cm)"``.
    """
    if not support:
        return []
    raw = np.asarray(raw_xyz_cm, dtype=float)
    reasons = []
    if n_inputs >= 2:
        coords = (raw - np.asarray(support["center_cm"])) @ np.asarray(support["axes"]).T
        lo, hi = np.asarray(support["min_cm"]), np.asarray(support["max_cm"])
        margin = np.asarray(support["margin_cm"])
        beyond = np.maximum(lo - coords, coords - hi)
        # Only the thinnest direction says "off the surface"; the wide ones are the valid_range's
        # job.
        thin = int(np.argmin(hi - lo))
        if beyond[thin] > margin[thin]:
            reasons.append(
                f"{beyond[thin]:.2f} cm off the training placements' surface "
                f"(margin {margin[thin]:.2f} cm)"
            )
    correction = float(np.linalg.norm(np.asarray(corrected_xyz_cm, dtype=float) - raw))
    limit = CORRECTION_FACTOR * float(support["max_correction_cm"]) + 3.0 * float(
        support["residual_rms_cm"]
    )
    if correction > limit:
        reasons.append(
            f"a correction of {correction:.2f} cm, larger than any in training "
            f"(max {float(support['max_correction_cm']):.2f} cm)"
        )
    return reasons
