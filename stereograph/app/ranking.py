"""How ``stereograph compare`` shows and ranks variants: a setting as text, the best row.

Shared by the terminal table (:mod:`stereograph.app.compare`) and the page
(:mod:`stereograph.app.compare_report`). Public names: :data:`PER_PAIR`, :func:`show`,
:func:`best_row`, :func:`is_best`.
"""

from __future__ import annotations

import json
from typing import Any

from stereograph.core.errors import UsageError

PER_PAIR = "per_pair_s"  # the column of each variant's time per pair


def show(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


RANK = {"min": lambda v: v, "max": lambda v: -v, "abs": abs}


def best_row(res: Any, best: str | None) -> tuple[str, str, float] | None:
    """``(metric, how, ranked value)`` of the best row for ``--best NAME`` (lowest), ``NAME:max``
    (highest) or ``NAME:abs`` (closest to zero); None when no variant that ran to the end has a
    value."""
    if not best:
        return None
    name, _, how = best.partition(":")
    how = how or "min"
    if name not in res.metric_names:
        raise UsageError(
            f"--best {best}: no metric '{name}'",
            hint="choose one of " + ", ".join(res.metric_names),
        )
    if how not in RANK:
        raise UsageError(
            f"--best {best}: '{how}' is not a way to rank",
            hint=f"use {name}, {name}:max (highest is "
            f"best) or {name}:abs (closest to zero is best)",
        )
    # Only a variant that ran to the end can be best: a failed one's numbers cover the items that
    # got through (its hardest ones may be the ones missing), so they are shown but never ranked.
    vals = [
        RANK[how](r[name])
        for r in res.rows
        if r.get("ok") and isinstance(r.get(name), (int, float))
    ]
    return (name, how, min(vals)) if vals else None


def is_best(top: tuple[str, str, float] | None, row: dict[str, Any]) -> bool:
    if top is None or not row["ok"] or not isinstance(row.get(top[0]), (int, float)):
        return False
    return RANK[top[1]](row[top[0]]) == top[2]
