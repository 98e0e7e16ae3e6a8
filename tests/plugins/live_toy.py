"""Toy nodes for the --repeat loop tests: a live counter source (kept open across cycles) and a
checker."""

from __future__ import annotations

import time
from pathlib import Path

from stereograph.api import Field, In, NodeError, Out, Params, node


class TickParams(Params):
    stop_after: int = Field(1000, ge=0, description="Ticks before the source 'ends' (count).")
    sleep_s: float = Field(0.0, ge=0, description="Time each tick takes, seconds.")
    marker: str = Field("", description="File touched when the source is closed (tests).")
    warn_on: int = Field(
        0, ge=0, description="Give a warning on this tick, as a rewound recording does (0: never)."
    )
    interrupt_on: int = Field(
        0,
        ge=0,
        description="Be interrupted (Ctrl-C) on this tick and say how it stopped (0: never).",
    )
    done_after: int = Field(
        0, ge=0, description="Ask the loop to stop after this tick: the work is done (0: never)."
    )


class Ticker:
    """A stand-in for a device: counts, and says when it was closed."""

    def __init__(self, marker: str):
        self.n, self.marker = 0, marker

    def close(self) -> None:
        if self.marker:
            Path(self.marker).write_text(f"closed after {self.n}")


@node("toy.ticker", outputs={"tick": Out("Number")}, params=TickParams, cacheable=False)
def ticker(params: TickParams, ctx=None):
    """Counts 1, 2, 3, ... from one cycle to the next (an uncacheable source)."""
    t = ctx.resource("ticker", lambda: Ticker(params.marker))
    if t.n >= params.stop_after:
        raise NodeError(f"the ticker ended after {t.n} ticks", hint="raise stop_after")
    time.sleep(params.sleep_s)
    t.n += 1
    # as an actuator does: end safely, say what it did, let the interrupt go on
    if t.n == params.interrupt_on:
        e = KeyboardInterrupt()
        e.add_note(f"ticker: Ctrl-C during tick {t.n}: held still")
        raise e
    if t.n == params.warn_on:
        ctx.warn(f"tick {t.n} came from a rewound source")
    if t.n == params.done_after:
        ctx.stop_loop(f"counted to {t.n}")
    return {"tick": t.n}


class CheckParams(Params):
    fail_on_multiple_of: int = Field(
        0, ge=0, description="Fail when the tick is a multiple of this (0: never)."
    )
    lasting_from: int = Field(
        0, ge=0, description="From this tick on, fail for good (NodeError lasting; 0: never)."
    )


@node(
    "toy.check",
    inputs={"tick": In("Number"), "offset": In("Number")},
    outputs={"result": Out("Number")},
    params=CheckParams,
)
def check(params: CheckParams, tick, offset):
    """tick + offset, or a failure on chosen ticks (a 'nothing found' cycle)."""
    if params.lasting_from and tick >= params.lasting_from:
        raise NodeError(f"the device behind tick {tick} is gone", hint="plug it in", lasting=True)
    if params.fail_on_multiple_of and tick % params.fail_on_multiple_of == 0:
        raise NodeError(f"tick {tick} refused", hint="none needed")
    return {"result": tick + offset}


class ConstantParams(Params):
    fail: bool = Field(False, description="Fail instead (a file that cannot be loaded, say).")


@node("toy.constant", outputs={"value": Out("Number")}, params=ConstantParams)
def constant(params: ConstantParams):
    """A cacheable upstream value (counts its own runs in an environment-free way: it is just 7)."""
    if params.fail:
        raise NodeError("the constant could not be loaded", hint="none")
    return {"value": 7}
