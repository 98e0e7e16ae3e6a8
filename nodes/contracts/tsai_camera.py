"""Tsai's camera model, forward: world points to the distorted pixels a Tsai camera sees.

The model ``calibrator.tsai`` fits, and the one the synthetic Tsai target source renders with.
A camera is a dict of ``R`` (3x3), ``t_cm`` (3,), ``f`` (px), ``k1`` (1/px^2), ``dx``, ``dy``,
``ncx_over_nfx``, ``sx``, ``u0``, ``v0``. Public name: :func:`tsai_project`.
"""

from __future__ import annotations

import numpy as np


def tsai_project(cam: dict, world_cm: np.ndarray) -> np.ndarray:
    """Project world points (N, 3, cm) with a Tsai camera (see :func:`tsai_camera`) to pixels (N,
    2)."""
    P = np.asarray(world_cm, float) @ cam["R"].T + cam["t_cm"]
    Xu, Yu = cam["f"] * P[:, 0] / P[:, 2], cam["f"] * P[:, 1] / P[:, 2]
    ru = np.hypot(Xu, Yu)
    rd = ru.copy()
    k1 = cam["k1"]
    for _ in range(30):  # Newton on rd (1 + k1 rd^2) = ru
        g = rd * (1 + k1 * rd * rd) - ru
        rd = rd - g / (1 + 3 * k1 * rd * rd)
    s = np.where(ru > 0, rd / np.where(ru > 0, ru, 1), 1.0)
    Xd, Yd = Xu * s, Yu * s
    dxp = cam["dx"] * cam["ncx_over_nfx"]
    return np.stack([cam["sx"] * Xd / dxp + cam["u0"], Yd / cam["dy"] + cam["v0"]], axis=1)
