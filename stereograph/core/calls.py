"""One call of a node function: :class:`Task` in, :class:`TaskResult` out (:func:`execute`).

A module of its own, apart from the scheduler (:mod:`stereograph.core.runner`), so that running one
node without the scheduler -- a replayed rerun's node that must run
(:mod:`stereograph.app.rerun`) -- imports the node API and the registry only: not the cache's
codecs, NumPy or the streaming machinery.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stereograph.core import registry
from stereograph.core.api import REGISTRY, NodeError, RunContext
from stereograph.core.checks import ARTIFACT_CHECKS
from stereograph.core.errors import ConfigError

# The run's progress display, for nodes that report progress inside a call (ctx.progress). A
# context variable, not a Task field: the display cannot travel to worker processes (there
# ctx.progress is a no-op and the per-item count still advances).
_PROGRESS: contextvars.ContextVar[Any] = contextvars.ContextVar(
    "stereograph_progress", default=None
)


@contextlib.contextmanager
def progress_to(progress: Any) -> Iterator[None]:
    """While it lasts, node calls in this thread report their progress (``ctx.progress``) to
    ``progress`` (None: nowhere)."""
    token = _PROGRESS.set(progress)
    try:
        yield
    finally:
        _PROGRESS.reset(token)


def _progress_hook(node_name: str) -> Callable[[float, float, str], None] | None:
    report = getattr(_PROGRESS.get(), "item_progress", None)
    if report is None:
        return None
    return lambda done, total, unit: report(node_name, done, total, unit)


@dataclass
class Task:
    """One call of a node function (picklable, for process pools)."""

    node_type: str
    plugins: list[str]
    params: Any
    inputs: dict[str, Any]
    node_name: str
    item: str | None
    out_dir: str
    pipeline_dir: str
    input_types: dict[str, str] = field(default_factory=dict)
    resources: dict[str, Any] | None = None  # objects kept open for the run (this process only)
    producing: bool = False  # the node produces its collections item by item (``items=``)
    # gather port -> {item: why} (RunContext.lost)
    lost: dict[str, dict[str, str]] = field(default_factory=dict)


@dataclass
class TaskResult:
    ok: bool
    outputs: dict[str, Any] | None = None
    seconds: float = 0.0
    messages: list[str] = field(default_factory=list)
    error: str | None = None
    hint: str | None = None
    trace: str | None = None
    user_error: bool = False
    lasting: bool = False  # NodeError(lasting=True): every later call would fail the same way


def execute(task: Task) -> TaskResult:
    """Run one node call; never raises (failures come back as a TaskResult)."""
    t0 = time.perf_counter()
    try:
        spec, out, ctx = _call(task)
        if task.producing:
            _check_part(spec, task.item, out)
        else:
            out = _as_outputs(spec, out)
        _check_shapes(spec, out, task.producing)
        return TaskResult(True, out, time.perf_counter() - t0, ctx.messages if ctx else [])
    except NodeError as e:
        failure = dict(error=e.message, hint=e.hint, user_error=True, lasting=e.lasting)
        trace = traceback.format_exc()
    except ConfigError as e:
        failure, trace = dict(error=str(e), user_error=True), traceback.format_exc()
    except Exception as e:  # a bug in a node: keep the traceback for --debug
        failure, trace = dict(error=f"{type(e).__name__}: {e}"), traceback.format_exc()
    return TaskResult(False, None, time.perf_counter() - t0, [], trace=trace, **failure)


@functools.lru_cache(maxsize=1024)
def _folder(*parts: str) -> Path:
    """One immutable Path per folder, not one per call (parsing a path costs more than a call of a
    light node)."""
    return Path(*parts)


def _call(task: Task) -> tuple[Any, Any, RunContext | None]:
    """``(spec, what the node returned, its context)``: the node's function called on the task."""
    # a worker's first call, or a plugin file changed since (a long-lived Dask worker)
    if task.plugins:
        registry.import_plugins(task.plugins, _folder(task.pipeline_dir))
    spec = REGISTRY.get(task.node_type) or registry.get(task.node_type)
    params = task.params
    if isinstance(params, dict):  # sent as plain data to another process: validate again there
        params = spec.params.model_validate(params)
    kwargs = dict(task.inputs)
    ctx = None
    if spec.wants_ctx:
        ctx = kwargs["ctx"] = RunContext(
            task.node_name,
            task.item,
            _folder(task.out_dir, task.node_name),
            _folder(task.pipeline_dir),
            input_types=task.input_types,
            resources=task.resources,
            on_progress=_progress_hook(task.node_name),
            producing_items=task.producing,
            lost=task.lost,
        )
    return spec, spec.fn(params, **kwargs), ctx


def _as_outputs(spec: Any, out: Any) -> dict[str, Any]:
    """A node's return value as ``{output: value}``: a node of one output may return the value."""
    if isinstance(out, dict) and set(out) == set(spec.outputs):
        return out
    if len(spec.outputs) == 1:
        return {next(iter(spec.outputs)): out}
    if not isinstance(out, dict):
        raise TypeError(
            f"{spec.name} returned {type(out).__name__}, expected a dict of its outputs"
        )
    missing, extra = set(spec.outputs) - set(out), set(out) - set(spec.outputs)
    raise TypeError(
        f"{spec.name} returned outputs {sorted(out)}; missing {sorted(missing)}"
        + (f", unexpected {sorted(extra)}" if extra else "")
    )


def _check_shapes(spec: Any, out: dict[str, Any], producing: bool) -> None:
    """Each output's value against its declared type's registered check
    (:func:`api.artifact_check`); a collection made whole is checked item by item. Raises NodeError
    naming the output."""

    for name, value in out.items():
        decl = spec.outputs.get(name)
        check = ARTIFACT_CHECKS.get(decl.type) if decl is not None else None
        if check is None or value is None:
            continue
        whole = decl.collection and not producing and isinstance(value, dict)
        for item, v in value.items() if whole else [(None, value)]:
            why = check(v)
            if why:
                at = f" for item {item!r}" if item is not None else ""
                raise NodeError(
                    f"{spec.name}: its output '{name}'{at} is not a {decl.type}: {why}",
                    hint=f"return a {decl.type} as docs/artifacts.md describes it (the node "
                    "that reads "
                    "it would only see a malformed input)",
                )


def _check_part(spec: Any, item: str | None, out: Any) -> None:
    """An item-producing node returns its collections' values for one item, or its other outputs."""
    colls = {n for n, o in spec.outputs.items() if o.collection}
    want = colls if item is not None else set(spec.outputs) - colls
    got = set(out) if isinstance(out, dict) else None
    if got is None or not got <= want or (item is None and got != want):
        raise TypeError(
            f"{spec.name} produces items: called for "
            + (
                f"item {item!r} it must return a dict with "
                f"keys among {sorted(want)} (or {{}} to drop the item)"
                if item is not None
                else f"its other outputs it must return a dict of {sorted(want)}"
            )
            + f", got {sorted(got) if got is not None else type(out).__name__}"
        )


def close_resources(resources: dict[str, Any]) -> None:
    """Close what nodes kept open with ``ctx.resource`` (last opened first); never raises."""
    for obj in reversed(list(resources.values())):
        close = getattr(obj, "close", None) or getattr(obj, "release", None)
        if close is not None:
            with contextlib.suppress(Exception):
                close()
    resources.clear()
