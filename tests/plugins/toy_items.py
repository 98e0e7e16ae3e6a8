"""A toy source that produces its collection item by item (``items=``), for engine tests."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stereograph.api import Field, In, NodeError, Out, Params, node


class ProduceParams(Params):
    n: int = Field(4, ge=0, le=10_000, description="How many items (count).")
    size: int = Field(8, ge=1, description="Side of each item's array (elements).")
    drop: list[str] = Field(
        default_factory=list, description="Item ids the node drops with a warning."
    )
    fail: list[str] = Field(
        default_factory=list, description="Item ids the node fails on (NodeError)."
    )
    kill_once: str | None = Field(
        None, description="Marker file: the first call for item m001 kills its process."
    )
    kill_always: str | None = Field(None, description="Item id whose every call kills its process.")
    log: str | None = Field(
        None,
        description="File: each item call appends its process id, whether the process "
        "prepared for items then (once per process) and its OpenCV thread "
        "setting.",
    )


_PREPARED: set[str] = set()  # logs this process has prepared for (see ``log``)


def _ids(params: ProduceParams, ctx) -> list[str]:
    return [f"m{i:03d}" for i in range(params.n)]


@node(
    "toy.produce",
    outputs={"items": Out("Matrix", collection=True), "count": Out("Number")},
    params=ProduceParams,
    items=_ids,
)
def produce(params: ProduceParams, ctx=None):
    """Random matrices seeded by item number, produced one per call; ``count`` is the whole part."""
    if ctx is None or not ctx.producing_items:  # a direct call: everything
        return {"items": {i: _one(params, i) for i in _ids(params, ctx)}, "count": params.n}
    if ctx.item is None:
        return {"count": params.n}
    if params.kill_once and ctx.item == "m001" and not Path(params.kill_once).exists():
        Path(params.kill_once).write_text("killed")
        os._exit(3)  # the worker dies mid-task
    if ctx.item == params.kill_always:
        os._exit(3)
    # what a process prepares once for its items (a plan, lookup tables), like source.synthetic
    if params.log:
        fresh = params.log not in _PREPARED
        _PREPARED.add(params.log)
        with open(params.log, "a") as f:
            f.write(f"{os.getpid()} {int(fresh)} {os.environ.get('OPENCV_FOR_THREADS_NUM', '-')}\n")
    if ctx.item in params.fail:
        raise NodeError(f"item {ctx.item} is broken (on purpose)")
    if ctx.item in params.drop:
        ctx.warn(f"item {ctx.item} dropped (on purpose)")
        return {}
    return {"items": _one(params, ctx.item)}


def _one(params: ProduceParams, item: str) -> np.ndarray:
    return np.random.default_rng(int(item[1:])).normal(size=(params.size, params.size))


@node("toy.scale", inputs={"m": In("Matrix"), "k": In("Number")}, outputs={"m": Out("Matrix")})
def scale(params, m, k):
    """One item's matrix over a whole value (here: a sum over every item)."""
    return {"m": m / k}
