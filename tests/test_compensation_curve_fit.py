"""The disparity curve's nonlinear fit (scipy.optimize.least_squares) reaches the least-squares
optimum."""

from __future__ import annotations

import numpy as np

from nodes.compensators.disparity_curve import _curve, fit_disparity_curve
from nodes.contracts.compensator._common import samples_from_locations


def _samples(d, z_true):
    locs = {
        f"p{i}": {
            "pair": f"p{i}",
            "found": True,
            "x_cm": 0.0,
            "y_cm": 0.0,
            "z_cm": float(z_true[i] * 1.02),
            "disparity_px": float(d[i]),
            "u_left_px": 320.0,
            "v_left_px": 240.0,
            "truth_cm": [0.0, 0.0, float(z_true[i])],
            "split": "train",
            "frame": "left_camera",
        }
        for i in range(len(d))
    }
    return samples_from_locations(locs)


def test_noisy_fit_is_a_least_squares_minimum():
    rng = np.random.default_rng(7)
    d = rng.uniform(40, 220, 40)
    z = 7800.0 / (d + 2.5) - 0.8 + rng.normal(0, 0.3, d.size)  # cm; 3 mm depth noise
    coef = fit_disparity_curve(_samples(d, z), rectified=False)
    p = np.array([coef["a_cm_px"], coef["b_px"], coef["c_cm"]])
    cost = np.sum((_curve(p, d) - z) ** 2)
    # no small step along any coefficient lowers the sum of squares: the fit sits at the minimum
    for k, step in enumerate((1.0, 0.01, 0.001)):
        for sign in (-1, 1):
            q = p.copy()
            q[k] += sign * step
            assert np.sum((_curve(q, d) - z) ** 2) >= cost - 1e-9
    assert abs(coef["b_px"] - 2.5) < 3.0 and coef["iterations"] >= 1
