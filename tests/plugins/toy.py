"""Toy nodes for engine tests and pipelines/hello.yaml (not part of the built-in library)."""

from __future__ import annotations

import numpy as np

from stereograph.api import Field, In, NodeError, Out, Params, node


class NumbersParams(Params):
    n: int = Field(5, ge=0, le=10_000, description="How many items (count).")
    size: int = Field(64, ge=1, description="Side of each item's array (elements).")
    seed: int = Field(0, ge=0, description="Random seed (NumPy needs it non-negative).")


@node("toy.numbers", outputs={"items": Out("Matrix", collection=True)}, params=NumbersParams)
def numbers(params: NumbersParams):
    """A collection of random square matrices, one per item."""
    rng = np.random.default_rng(params.seed)
    return {
        "items": {f"m{i:03d}": rng.normal(size=(params.size, params.size)) for i in range(params.n)}
    }


class PowerParams(Params):
    power: int = Field(2, ge=1, le=64, description="Matrix power (unitless).")
    fail_on: str | None = Field(None, description="Item id to fail on (for tests).")
    interrupt_on: str | None = Field(
        None, description="Item id to raise KeyboardInterrupt on, as Ctrl-C (tests)."
    )


@node(
    "toy.power",
    inputs={"m": In("Matrix")},
    outputs={"m": Out("Matrix"), "norm": Out("Number")},
    params=PowerParams,
)
def power(params: PowerParams, m, ctx=None):
    """Matrix power (real work: a few matrix products)."""
    if params.interrupt_on is not None and ctx is not None and ctx.item == params.interrupt_on:
        raise KeyboardInterrupt
    if params.fail_on is not None and ctx is not None and ctx.item == params.fail_on:
        raise NodeError(f"asked to fail on {ctx.item}", hint="unset fail_on")
    out = np.linalg.matrix_power(m / np.linalg.norm(m), params.power)
    return {"m": out, "norm": float(np.linalg.norm(out))}


class SumParams(Params):
    scale: float = Field(1.0, description="Multiplier (unitless).")


@node(
    "toy.sum",
    inputs={"values": In("Number", gather=True)},
    outputs={"total": Out("Number", save=True)},
    params=SumParams,
)
def total(params: SumParams, values):
    """Sum of all items (a reduce)."""
    return {"total": params.scale * float(sum(values.values()))}


PREPARED: list[str] = []  # the threads toy.table's prepare() ran in (the test process's runs)


def _prepare_table() -> None:
    import threading

    PREPARED.append(threading.current_thread().name)


@node(
    "toy.table",
    inputs={"m": In("Matrix", gather=True)},
    outputs={"report": Out("Report")},
    prepare=_prepare_table,
)
def table(params, m):
    """Shape report of all items (its ``prepare`` only records where it ran)."""
    return {"report": {"n": len(m), "items": sorted(m)}}


@node(
    "toy.picture",
    inputs={"m": In("Matrix")},
    outputs={"picture": Out("Image", save=True), "mean": Out("Number")},
)
def picture(params, m):
    """A grey image of the matrix (saved to the run folder on every run)."""
    img = (255 * (m - m.min()) / max(float(np.ptp(m)), 1e-9)).astype(np.uint8)
    return {"picture": np.kron(img, np.ones((4, 4), np.uint8)), "mean": float(m.mean())}


@node("toy.describe", inputs={"x": In("Matrix | Number")}, outputs={"kind": Out("Report")})
def describe(params, x, ctx=None):
    """Accepts a Matrix or a Number and reports which one the pipeline wired (ctx.input_types)."""
    return {"kind": {"wired": ctx.input_types["x"], "is_array": isinstance(x, np.ndarray)}}
