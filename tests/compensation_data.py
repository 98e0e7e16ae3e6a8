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
    misdetect_fraction: float = 0.0,
    misdetect_offset_cm: tuple[float, float] = (15.0, 40.0),
    table_plane_cm: tuple[float, float] | None = None,
) -> dict[str, dict]:
    """Return {item_id: Location} with split, truth and the raw measurement inputs.

    ``baseline_scale`` is believed/true baseline (1.02 = 2 % baseline error);
    ``disparity_offset_px`` is added to every measured disparity.
    ``misdetect_fraction`` of the *train* items measure a distractor ball instead of the one
    whose truth they carry: a ball ``misdetect_offset_cm`` away (random direction, kept in front
    of the camera and in the image), seen through the same imperfect rig. Those items are marked
    ``"misdetected": True``; every other item is identical to the data without mis-detections.
    ``table_plane_cm = (a, b)`` puts every ball on a table, the plane y = a + b z (cm), as a bench's
    training placements are (the default spreads them through the volume).
    """
    rng = np.random.default_rng(seed)
    z = rng.uniform(*z_range_cm, n)
    u_true = rng.uniform(40, 2 * cx - 40, n)
    v_true = rng.uniform(40, 2 * cy - 40, n)
    x = (u_true - cx) * z / f_px
    y = (v_true - cy) * z / f_px
    if table_plane_cm is not None:
        y = table_plane_cm[0] + table_plane_cm[1] * z
        v_true = cy + f_px * y / z
    d_true = f_px * baseline_cm / z
    u = u_true + rng.normal(0, noise_px, n)
    v = v_true + rng.normal(0, noise_px, n)
    d = d_true + disparity_offset_px + rng.normal(0, noise_px, n)
    b_believed = baseline_cm * baseline_scale
    zm = f_px * b_believed / d
    xm = (u - cx) * zm / f_px
    ym = (v - cy) * zm / f_px
    split = np.where(rng.random(n) < train_fraction, "train", "test")
    misdetected = np.zeros(n, dtype=bool)
    if misdetect_fraction > 0:
        # A separate generator: the clean items stay bit-identical to the data without distractors.
        mrng = np.random.default_rng(seed + 7919)
        train_idx = np.flatnonzero(split == "train")
        pick = mrng.choice(
            train_idx, size=int(round(misdetect_fraction * len(train_idx))), replace=False
        )
        for i in pick:
            for _ in range(100):
                direction = mrng.normal(size=3)
                direction /= np.linalg.norm(direction)
                p = np.array([x[i], y[i], z[i]]) + mrng.uniform(*misdetect_offset_cm) * direction
                if p[2] < 15:
                    continue
                ud, vd = cx + f_px * p[0] / p[2], cy + f_px * p[1] / p[2]
                if 10 < ud < 2 * cx - 10 and 10 < vd < 2 * cy - 10:
                    break
            u[i] = ud + mrng.normal(0, noise_px)
            v[i] = vd + mrng.normal(0, noise_px)
            d[i] = f_px * baseline_cm / p[2] + disparity_offset_px + mrng.normal(0, noise_px)
            zm[i] = f_px * b_believed / d[i]
            xm[i] = (u[i] - cx) * zm[i] / f_px
            ym[i] = (v[i] - cy) * zm[i] / f_px
            misdetected[i] = True
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
            "misdetected": bool(misdetected[i]),
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
