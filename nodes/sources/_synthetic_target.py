"""Synthetic Tsai calibration targets seen by the synthetic rig's two cameras, modelled as Tsai
cameras.

Used by the Tsai benchmark, the tests and ``pipelines/examples/make_tsai_example.py``. The world
frame is the rig's table frame (cm; x right, y away from the cameras, z up). Two targets:

* ``coplanar``: a grid of points on the table (z = 0), e.g. a printed sheet of dots.
* ``non_coplanar``: the same grid in front of a vertical wall plus a grid on that wall (a
  two-plane "corner" target, the classic 3-D target of Tsai's method).

Only points inside both images (with a margin) are kept. The cameras follow Tsai's model exactly
(radial k1, distorted -> undistorted, see ``nodes/calibrators/tsai.py``), so the recovered f, k1,
R and T can be compared with a known truth.
"""

from __future__ import annotations

import numpy as np

from nodes.contracts.tsai_camera import tsai_project
from nodes.sources._lens import project_points

__all__ = ["opencv_pixels", "target_points", "tsai_cameras"]


def tsai_cameras(rig: dict, kappa_left: float = 0.15, kappa_right: float = 0.12) -> list[dict]:
    """The rig's cameras as Tsai cameras (world = table frame), with normalised k1 ``kappa_*``.

    Returns ``[left, right]``, each a dict :func:`tsai_project` takes (``f`` px, ``k1`` 1/px^2,
    ``sx``, ``R``, ``t_cm``, ``u0``, ``v0``, ``dx = dy = 1``, ``ncx_over_nfx = 1``).
    """
    tr = rig["truth"]
    T = np.asarray(tr["T_table_from_left"], float)
    Rw = T[:3, :3].T  # table -> left camera
    tl = -Rw @ T[:3, 3]
    poses = ((Rw, tl), (tr["R"] @ Rw, tr["R"] @ tl + tr["T_cm"]))
    cams = []
    for (K, kappa), (Rx, tx) in zip(((tr["K1"], kappa_left), (tr["K2"], kappa_right)), poses):
        cams.append(
            {
                "f": float(K[1, 1]),
                "k1": kappa / K[1, 1] ** 2,
                "sx": float(K[0, 0] / K[1, 1]),
                "R": Rx,
                "t_cm": np.asarray(tx, float),
                "u0": float(K[0, 2]),
                "v0": float(K[1, 2]),
                "dx": 1.0,
                "dy": 1.0,
                "ncx_over_nfx": 1.0,
            }
        )
    return cams


def target_points(
    rig: dict,
    cams: list[dict],
    kind: str = "coplanar",
    spacing_cm: float = 2.5,
    heights_cm: tuple[float, ...] = (0.0, 5.0, 10.0),
    margin_px: float = 8.0,
):
    """World points (N, 3, cm) of a target and their exact left and right pixels (N, 2 each).

    Parameters
    ----------
    kind : {"coplanar", "non_coplanar"}
        A grid on the table, or the grid in front of a wall plus a grid on the wall at
        ``wall_y_cm``.
    spacing_cm : float
        Grid spacing, cm.
    margin_px : float
        Points closer than this to an image border (in either camera) are dropped.
    """
    g = np.arange(-40.0, 40.0 + 1e-9, spacing_cm)
    X, Y = np.meshgrid(g, np.arange(-30.0, 50.0 + 1e-9, spacing_cm))
    pts = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    if kind == "non_coplanar":
        pts = np.vstack([pts + [0.0, 0.0, z] for z in heights_cm])
    elif kind != "coplanar":
        raise ValueError(f"kind must be coplanar or non_coplanar, not {kind!r}")
    w, h = rig["truth"]["image_size"]
    keep = np.ones(len(pts), bool)
    pix = []
    for cam in cams:
        keep &= (pts @ cam["R"].T + cam["t_cm"])[:, 2] > 1.0
        p = tsai_project(cam, pts)
        pix.append(p)
        keep &= (p[:, 0] >= margin_px) & (p[:, 0] <= w - 1 - margin_px)
        keep &= (p[:, 1] >= margin_px) & (p[:, 1] <= h - 1 - margin_px)
    return pts[keep], pix[0][keep], pix[1][keep]


def opencv_pixels(rig: dict, world_cm: np.ndarray, margin_px: float = 5.0):
    """The same world points seen through the rig's own OpenCV cameras (k1 k2 p1 p2: not Tsai's
    model).

    Returns ``(world_cm, left_px, right_px)`` for the points inside both images (with the margin):
    a lens that Tsai's radial-k1 model does not describe exactly, as real lenses.
    """
    tr = rig["truth"]
    Tl = np.linalg.inv(np.asarray(tr["T_table_from_left"], float))
    P = np.asarray(world_cm, float) @ Tl[:3, :3].T + Tl[:3, 3]
    L = project_points(tr["K1"], tr["D1"], P)
    R = project_points(tr["K2"], tr["D2"], P @ tr["R"].T + tr["T_cm"])
    w, h = tr["image_size"]
    ok = np.ones(len(P), bool)
    for p in (L, R):
        ok &= (p[:, 0] >= margin_px) & (p[:, 0] <= w - 1 - margin_px) & (p[:, 1] >= margin_px)
        ok &= p[:, 1] <= h - 1 - margin_px
    return np.asarray(world_cm, float)[ok], L[ok], R[ok]
