"""Synthetic Location records with a known systematic error, for the compensator tests.

A pinhole stereo rig (f px, baseline B cm) measures balls at random positions; the
"believed" calibration has a wrong baseline (scale error) and the disparity a constant
offset, so z (and x, y along the ray) carry a systematic error plus pixel noise.
"""

from __future__ import annotations

import numpy as np


def make_locations(
    n: int = 120,
    seed: int = 0,
    f_px: float = 800.0,
    cx: float = 320.0,
    cy: float = 240.0,
    baseline_cm: float = 10.0,
    baseline_scale: float = 1.0,
    disparity_offset_px: float = 0.0,
    noise_px: float = 0.1,
    z_range_cm: tuple[float, float] = (30.0, 90.0),
    train_fraction: float = 0.5,
) -> dict[str, dict]:
    """Return {item_id: Location} with split, truth and the raw measurement inputs.

    ``baseline_scale`` is believed/true baseline (1.02 = 2 % baseline error);
    ``disparity_offset_px`` is added to every measured disparity.
    """
    rng = np.random.default_rng(seed)
    z = rng.uniform(*z_range_cm, n)
    u_true = rng.uniform(40, 2 * cx - 40, n)
    v_true = rng.uniform(40, 2 * cy - 40, n)
    x = (u_true - cx) * z / f_px
    y = (v_true - cy) * z / f_px
    d_true = f_px * baseline_cm / z
    u = u_true + rng.normal(0, noise_px, n)
    v = v_true + rng.normal(0, noise_px, n)
    d = d_true + disparity_offset_px + rng.normal(0, noise_px, n)
    b_believed = baseline_cm * baseline_scale
    zm = f_px * b_believed / d
    xm = (u - cx) * zm / f_px
    ym = (v - cy) * zm / f_px
    split = np.where(rng.random(n) < train_fraction, "train", "test")
    out = {}
    for i in range(n):
        pid = f"s{i:03d}"
        out[pid] = {
            "pair": pid,
            "found": True,
            "reason": None,
            "x_cm": float(xm[i]),
            "y_cm": float(ym[i]),
            "z_cm": float(zm[i]),
            "sigma_z_cm": float(zm[i] ** 2 / (f_px * b_believed) * noise_px),
            "frame": "left_camera",
            "disparity_px": float(d[i]),
            "u_left_px": float(u[i]),
            "v_left_px": float(v[i]),
            "truth_cm": [float(x[i]), float(y[i]), float(z[i])],
            "split": str(split[i]),
        }
    return out


def errors(locations: dict[str, dict], split: str = "test") -> np.ndarray:
    """measured - truth (N, 3) cm of the found items of a split."""
    rows = [
        np.subtract([loc["x_cm"], loc["y_cm"], loc["z_cm"]], loc["truth_cm"])
        for loc in locations.values()
        if loc.get("split") == split and loc.get("found")
    ]
    return np.array(rows).reshape(-1, 3)
