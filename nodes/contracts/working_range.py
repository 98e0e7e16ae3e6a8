"""Which working range a node uses: its own, when the pipeline sets it, else the one its upstream
record carries.

A contract between kinds: a segmenter puts its ``working_range_cm`` into each Segmentation, a
disparity estimator passes the one it used on in each Disparity, so that a range set on the
segmenter alone (``--set segment.working_range_cm=[80,220]``) holds down the chain instead of the
next nodes refusing everything outside their own default 20-80 cm.
"""

from __future__ import annotations

from typing import Any

__all__ = ["working_range"]


def working_range(params: Any, record: Any) -> tuple[float, float]:
    """``(near, far)`` in cm: ``params.working_range_cm`` if the pipeline set it (YAML,
    ``defaults:``, ``--set``), else ``record["working_range_cm"]`` when the upstream record has one,
    else the params' default."""
    own = params.working_range_cm
    if "working_range_cm" in params.model_fields_set or not isinstance(record, dict):
        return tuple(sorted(float(z) for z in own))
    upstream = record.get("working_range_cm")
    if isinstance(upstream, (list, tuple)) and len(upstream) == 2:
        return tuple(sorted(float(z) for z in upstream))
    return tuple(sorted(float(z) for z in own))
