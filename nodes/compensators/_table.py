"""The compensators' apply table: model type -> (predict function, Location keys it reads).

:mod:`nodes.compensators.apply` dispatches on ``model["type"]`` through this
table. A new compensator adds its fit node (a file) and one line here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from nodes.compensators import disparity_curve, lookup, none, polynomial, xyz
from nodes.contracts.compensator._common import Samples

__all__ = ["PREDICTORS"]

Predict = Callable[[Mapping, Samples], np.ndarray]

#: model type -> (predict(coefficients, samples) -> xyz (N, 3) cm, Location keys it reads)
PREDICTORS: dict[str, tuple[Predict, tuple[str, ...]]] = {
    "none": (none.predict_none, none.INPUTS),
    "polynomial": (polynomial.predict_polynomial, polynomial.INPUTS),
    "disparity_curve": (disparity_curve.predict_disparity_curve, disparity_curve.INPUTS),
    "lookup": (lookup.predict_lookup, lookup.INPUTS),
    "xyz": (xyz.predict_xyz, xyz.INPUTS),
}
