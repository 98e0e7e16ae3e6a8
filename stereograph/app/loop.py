"""Run the live part of a pipeline again and again: ``run --repeat N`` or a pipeline's ``repeat:``.

The live part is every uncacheable node and what is downstream of one; cycle 1 runs the whole
graph, later cycles only the live part, in memory. Each cycle is one line of ``cycles.jsonl``.
The loop stops at the count, when a node asks (``ctx.stop_loop``), when the source of new input
or a node outside the live part fails, on a lasting failure, with ``stop_on_failure``, or on an
interrupt (which lets the running node clean up; ``run.json`` still counts every logged cycle).
Public: :class:`Loop` (the ``cycles`` hook of ``run_graph``), :class:`Cycle`. docs/live.md and
docs/engine.md ("The loop") say more.
"""

from __future__ import annotations

import contextlib
import json
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stereograph.core import outputs as outputs_mod
from stereograph.core.api import STOP_LOOP
from stereograph.core.errors import ConfigError

SMALL_JSON = 6000  # characters: larger values are left out of cycles.jsonl
_NOT_LOGGED = object()  # (a value cycles.jsonl leaves out: see _logged_value)


@dataclass
class Cycle:
    """One pass over the live part."""

    index: int
    status: str = "running"  # ok | failed | interrupted
    seconds: float = 0.0
    failed_node: str | None = None
    error: str | None = None
    hint: str | None = None  # the failed node's fix
    nodes: dict[str, dict[str, Any]] = field(default_factory=dict)
    values: dict[str, Any] = field(default_factory=dict)
    before_node: bool = False  # interrupted before ``failed_node``'s own code began

    def stopped_by_interrupt(self) -> str:
        """What ended the loop, said of this interrupted cycle."""
        k, node = self.index, self.failed_node
        if node is None:
            return f"stopped by an interrupt as cycle {k} began"
        if self.before_node:
            return f"stopped by an interrupt during cycle {k}, before node '{node}' began"
        return f"stopped by an interrupt during cycle {k} (node '{node}')"

    def line(self) -> str:
        """One line for the terminal, then one line per warning a live node gave in this cycle."""
        times = ", ".join(
            f"{n} {d['seconds'] * 1000:.0f} ms"
            for n, d in self.nodes.items()
            if d["status"] in ("ran", "partial", "failed")
        )
        head = f"cycle {self.index}: {self.status} in {self.seconds:.2f} s"
        if self.status == "failed":
            head += f" at {self.failed_node}: {self.error}" + (
                f" Fix: {self.hint}" if self.hint else ""
            )
        elif self.status == "interrupted":
            where = "before" if self.before_node else "during"
            head += f" ({where} {self.failed_node})" + (f": {self.error}" if self.error else "")
        notes = "".join(
            f"\n  note: {n}: {m}" for n, d in self.nodes.items() for m in d.get("messages", [])
        )
        return head + (f"  [{times}]" if times else "") + notes


@dataclass
class Loop:
    """The ``cycles`` hook of :func:`stereograph.core.runner.run_graph` that repeats the live part.

    Parameters
    ----------
    repeat : int
        Cycles to run; 0 = until interrupted (or the input ends).
    stop_on_failure : bool
        Stop at the first failed cycle instead of going on.
    save_cycles : bool
        Write every live output of every cycle into ``cycles/<n>/`` (images as PNG).
    on_cycle : callable, optional
        Called with each finished :class:`Cycle` (the CLI prints its line).
    stop_requested : callable, optional
        ``() -> str | None``: where a stop signal landed, once one was received (the CLI's). Checked
        before every node: an interrupt that some code swallowed still ends the loop at the next
        node.
    """

    repeat: int
    stop_on_failure: bool = False
    save_cycles: bool = False
    on_cycle: Callable[[Cycle], None] | None = None
    stop_requested: Callable[[], str | None] | None = None
    cycles: list[Cycle] = field(default_factory=list)
    live: list[str] = field(default_factory=list)
    stopped: str = ""  # why the loop ended, in words
    interrupted: bool = False
    finished: bool = False  # a node asked the loop to end (ctx.stop_loop): its work is done

    @property
    def n_ok(self) -> int:
        return sum(1 for c in self.cycles if c.status == "ok")

    def summary(self) -> str:
        failed = [c for c in self.cycles if c.status == "failed"]
        text = f"{len(self.cycles)} cycle(s): {self.n_ok} ok, {len(failed)} failed"
        if failed:
            reasons: dict[str, int] = {}
            for c in failed:
                reasons[f"{c.failed_node}: {c.error}"] = (
                    reasons.get(f"{c.failed_node}: {c.error}", 0) + 1
                )
            text += " (" + "; ".join(f"{n}x {r}" for r, n in list(reasons.items())[:3]) + ")"
        return text + f"; {self.stopped}"

    # ---- the hook

    def __call__(self, run: Any, selected: list[str]) -> None:
        g = run.g
        chosen = set(selected)
        seeds = [n for n in selected if not g.nodes[n].spec.cacheable]
        live = set()
        for n in seeds:
            live |= ({n} | g.downstream(n)) & chosen
        if not live:
            raise ConfigError(
                f"--repeat: every node of {g.doc.path.name} can be cached, so every cycle "
                "would give "
                "the same result.",
                hint="add a live node (a camera, an actuator) or drop --repeat",
            )
        self.live = [n for n in selected if n in live]
        # Kept in memory across cycles: what the live part reads, and each cycle's own values
        # until they are logged (the next cycle's reset drops them).
        held = {src for n in self.live for src in g.dag.predecessors(n) if src not in live} | live
        try:
            with run.cycling(live, held):
                self._cycles(run, selected, live, log_path=run.out_dir / "cycles.jsonl")
        finally:
            run.add_to_summary("loop", self.info())

    def info(self) -> dict[str, Any]:
        """What happened, for ``run.json``."""
        return {
            "repeat": self.repeat,
            "cycles": len(self.cycles),
            "ok": self.n_ok,
            "failed": sum(1 for c in self.cycles if c.status == "failed"),
            "interrupted": self.interrupted,
            "completed": self.completed,
            "stopped": self.stopped,
            "summary": self.summary(),
            "live": self.live,
            "log": "cycles.jsonl",
        }

    @property
    def completed(self) -> bool:
        """Ran every cycle asked for, or a node said its work is done (ctx.stop_loop)."""
        return self.finished or self.stopped.startswith("ran the ")

    def _cycles(self, run: Any, selected: list[str], live: set[str], log_path: Path) -> None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        log_path.write_text("")
        try:
            self._loop(run, selected, live, log_path)
        # outside any node: between two cycles, or while one was being logged
        except KeyboardInterrupt:
            self.interrupted = True
            k = len(self.cycles)
            self.stopped = f"stopped by an interrupt between cycles {k} and {k + 1}"

    def _loop(self, run: Any, selected: list[str], live: set[str], log_path: Path) -> None:
        g = run.g
        roots = {n for n in self.live if not (set(g.dag.predecessors(n)) & live)}
        k = 0
        while self.repeat == 0 or k < self.repeat:
            k += 1
            cycle = Cycle(k)
            order = selected if k == 1 else self.live
            t0 = time.perf_counter()
            current = None
            try:
                self._check_stop()
                if k > 1:  # (whole or not at all: a signal half-way would leave refs to nothing)
                    with _signals_deferred():
                        run.forget(self.live)
                for name in order:
                    current = name  # (a lost signal found here stops the loop before it begins)
                    self._check_stop()
                    run.run_node(g.nodes[name])
            except KeyboardInterrupt as e:
                order = self._interrupted(run, cycle, order, current, e)
            cycle.seconds = time.perf_counter() - t0
            # The log line and the count in run.json must agree: a signal here waits until both are
            # done.
            with _signals_deferred():
                self._record(run, cycle, order, log_path)
            if self.on_cycle is not None:
                self.on_cycle(cycle)
            if self.interrupted:
                self.stopped = cycle.stopped_by_interrupt()
                return
            asked = run.take_resource(STOP_LOOP)
            if asked is not None:
                self.stopped = f"stopped by node '{asked[0]}': {asked[1]}"
                self.finished = True
                return
            outside = [
                n for n in order if n not in live and run.reports[n].status in ("failed", "skipped")
            ]
            if outside:
                self.stopped = (
                    f"stopped: node '{outside[0]}' (outside the live part) failed, so "
                    "no cycle can run"
                )
                return
            if cycle.status == "failed" and cycle.failed_node in roots:
                self.stopped = f"stopped: '{cycle.failed_node}' gave no new input"
                return
            if cycle.status == "failed" and run.reports[cycle.failed_node].lasting:
                self.stopped = (
                    f"stopped: '{cycle.failed_node}' failed in a way no later cycle can change: a "
                    "person must see to it before another cycle runs"
                )
                return
            if cycle.status == "failed" and self.stop_on_failure:
                self.stopped = f"stopped at the first failed cycle ({k})"
                return
        self.stopped = f"ran the {self.repeat} cycle(s) asked for"

    def _interrupted(
        self, run: Any, cycle: Cycle, order: list[str], current: str | None, e: BaseException
    ) -> list[str]:
        """Note an interrupt in ``cycle`` (at node ``current``, None: before its first); returns
        the nodes whose reports this cycle stands for."""
        # what the interrupted node did to end safely, as it noted on the interrupt (an arm held)
        cycle.error = " ".join(getattr(e, "__notes__", ()) or [str(e)]) or None
        if current is None:  # a cycle that did not begin: the last one's reports stand
            order = []
        elif not _reached(e, run.g.nodes[current].spec.fn):
            # in the engine, before the node's own code began: it did nothing this cycle
            cycle.before_node = True
        for name in order:  # the interrupted node and those after it did not finish
            rep = run.reports[name]
            if rep.status in ("pending", "running"):
                rep.status, rep.error = "skipped", f"interrupted during cycle {cycle.index}"
        cycle.status, cycle.failed_node = "interrupted", current
        self.interrupted = True
        return order

    def _check_stop(self) -> None:
        """Raise the interrupt a stop signal should have raised, if it was lost on its way."""
        landed = self.stop_requested() if self.stop_requested is not None else None
        if landed:
            raise KeyboardInterrupt(
                f"a stop signal received in {landed} did not end the node it reached"
            )

    def _record(self, run: Any, cycle: Cycle, order: list[str], log_path: Path) -> None:
        g = run.g
        for name in order:
            r = run.reports[name]
            # (cycle 1 runs the rest too: its failure leaves the live part skipped)
            if name not in self.live:
                if cycle.status == "running" and r.status == "failed":
                    cycle.status, cycle.failed_node, cycle.error, cycle.hint = (
                        "failed",
                        name,
                        r.error,
                        r.hint,
                    )
                continue
            # its warnings too: the next cycle's reset drops the report, so they would reach no one
            cycle.nodes[name] = {
                "status": r.status,
                "seconds": round(r.seconds, 5),
                "error": r.error,
                "messages": list(r.messages),
            }
            if cycle.status == "running" and r.status in ("failed", "partial"):
                cycle.status, cycle.failed_node, cycle.error, cycle.hint = (
                    "failed",
                    name,
                    r.error,
                    r.hint,
                )
            for out in g.nodes[name].spec.outputs:
                logged = _logged_value(_value(run, name, out))
                if logged is not _NOT_LOGGED:
                    cycle.values[f"{name}.{out}"] = logged
            # every output with --save-cycles; else the pictures the node saves (Out(save=True)),
            # kept for every cycle as its other saved outputs are (in <node>/<output>.cycles.jsonl)
            _save(
                run,
                name,
                run.out_dir / "cycles" / f"{cycle.index:05d}",
                pictures_only=not self.save_cycles,
            )
            _append_saved(run, name, cycle.index)
        if cycle.status == "running":
            cycle.status = "ok"
        rec = {
            "cycle": cycle.index,
            "status": cycle.status,
            "seconds": round(cycle.seconds, 5),
            "failed_node": cycle.failed_node,
            "error": cycle.error,
            "hint": cycle.hint,
            "time": time.time(),
            "nodes": cycle.nodes,
            "values": cycle.values,
        }
        with log_path.open("a") as f:
            f.write(json.dumps(rec, default=str) + "\n")
        self.cycles.append(cycle)


def _logged_value(v: Any) -> Any:
    """What ``cycles.jsonl`` keeps of a live output's value: the value as JSON when it is small, a
    big mapping's scalar facts (ids, timestamps, flags), else :data:`_NOT_LOGGED` (an image of any
    size: a 1x1 placeholder was logged as [[[0, 0, 0]]])."""
    if v is None or outputs_mod.image_shaped(v, channels=(1, 3, 4)):
        return _NOT_LOGGED
    text = json.dumps(outputs_mod.to_json(v, {}), default=str)
    if len(text) <= SMALL_JSON and '"npz"' not in text:
        return json.loads(text)
    if isinstance(v, dict):
        small = {
            key: x for key, x in v.items() if isinstance(x, (int, float, str, bool)) or x is None
        }
        if small:
            return json.loads(json.dumps(outputs_mod.to_json(small, {})))
    return _NOT_LOGGED


@contextlib.contextmanager
def _signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back for the block; one that arrived is raised right after it.

    Only where the platform can (POSIX) and in the main thread, where Python runs its handlers.
    """
    can = (
        hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
    )
    held = {signal.SIGINT, signal.SIGTERM}
    if can:
        signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        if can:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, held)


def _value(run: Any, node: str, out: str) -> Any:
    """An output's value this cycle; a collection of one dict (a live cycle's usual single pair) as
    that dict."""
    v = run.value_of(node, out)
    if (
        run.g.is_collection(node, out)
        and v is not None
        and len(v) == 1
        and isinstance(next(iter(v.values())), dict)
    ):
        return next(iter(v.values()))
    return v


def _save(run: Any, node: str, folder: Path, pictures_only: bool = False) -> None:
    """Every output of ``node`` in this cycle: images as PNG (also images inside a dict), the rest
    as JSON; with ``pictures_only``, only the images the node saves (``Out(save=True)``)."""
    for out, decl in run.g.nodes[node].spec.outputs.items():
        v = _value(run, node, out)
        if v is None or (pictures_only and not (decl.save and outputs_mod.is_image(v))):
            continue
        stem = folder / node / out
        stem.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(v, dict):
            for key, x in v.items():
                if outputs_mod.is_image(x):
                    outputs_mod.write_value(stem.parent / f"{out}_{key}", x)
            v = {key: x for key, x in v.items() if not outputs_mod.is_image(x)}
        outputs_mod.write_value(stem, v)


def _append_saved(run: Any, node: str, index: int) -> None:
    """Each saved output (``Out(save=True)``) of a live node that is not a picture gets one line per
    cycle in ``<node>/<output>.cycles.jsonl``: the run folder's ``<node>/<output>.json`` holds the
    last cycle's only (a servo log, say)."""
    for out, decl in run.g.nodes[node].spec.outputs.items():
        v = _value(run, node, out)
        if not decl.save or v is None or outputs_mod.is_image(v):
            continue
        path = run.out_dir / node / f"{out}.cycles.jsonl"
        path.parent.mkdir(parents=True, exist_ok=True)
        # (large arrays are left out: they go to --save-cycles' .npz files)
        with path.open("a") as f:
            f.write(
                json.dumps({"cycle": index, out: outputs_mod.to_json(v, {})}, default=str) + "\n"
            )


def _reached(e: BaseException, fn: Any) -> bool:
    """Whether an interrupt reached a node's own code (``fn`` is on its traceback), rather than
    the engine before or around it; True when that cannot be told (``fn`` is not a function)."""
    code = getattr(fn, "__code__", None)
    tb = e.__traceback__
    while code is not None and tb is not None:
        if tb.tb_frame.f_code is code:
            return True
        tb = tb.tb_next
    return code is None
