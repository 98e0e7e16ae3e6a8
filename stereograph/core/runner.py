"""The scheduler: run a validated graph in topological order, with cached artifacts.

Each node gets its entries (one, or one per item) and each entry a key; an entry in the store
is not recomputed. A failed node stops its downstream, a failed item only that item's. Public:
:func:`run_graph`, :func:`run_pipeline`. Usage and the whole story: docs/engine.md.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereograph.core import ahead, project, run_folder, streaming
from stereograph.core.cache import ArtifactStore, CacheBusy, in_use
from stereograph.core.calls import close_resources, progress_to
from stereograph.core.config import load_pipeline
from stereograph.core.errors import ConfigError, did_you_mean
from stereograph.core.executors import SerialExecutor
from stereograph.core.graph import build_graph
from stereograph.core.project import cache_dir as project_cache_dir
from stereograph.core.project import new_run_id
from stereograph.core.run_result import Ref, RunResult
from stereograph.core.run_state import RunState

# (not imported at run time: a replayed rerun runs a node without NetworkX or YAML)
if TYPE_CHECKING:
    from stereograph.core.graph import Graph


def run_graph(
    graph: Graph,
    *,
    cache_dir: str | Path | None = None,
    out_dir: str | Path | None = None,
    use_cache: bool = True,
    only: str | None = None,
    from_node: str | None = None,
    executor: Any = None,
    progress: Any = None,
    run_id: str | None = None,
    write_outputs: bool = True,
    keep: set[str] | None = None,
    cycles: Callable[[RunState, list[str]], None] | None = None,
    prepare: Sequence[Callable[[], Any]] = (),
) -> RunResult:
    """Run a validated graph; see the module docstring.

    ``keep`` names extra (non-terminal) nodes whose outputs the result should hold.
    ``cycles(run, selected)``, if given, runs the selected nodes instead of the single pass
    (:func:`stereograph.app.loop.repeat`); objects nodes kept open are closed afterwards either way.
    ``prepare``: functions of no arguments that load what the caller needs once the run is over
    (what it prints with); with a local pool they run in the background thread that runs the
    nodes' own ``prepare`` while this process waits for the pool, else never.
    """
    t0 = time.perf_counter()
    selected, force = _selection(graph, only, from_node)
    run_id = run_id or new_run_id()
    runs = project.runs_dir(graph.doc.directory)
    out = Path(out_dir) if out_dir else runs / graph.doc.name / run_id
    foreign = run_folder.prepare_out_dir(out)
    store, budget = _open_store(graph.doc, cache_dir, use_cache)
    own_executor = executor is None
    executor = executor or SerialExecutor()
    lease = _lease(executor, store, out)
    # the result holds the terminal nodes (--only's node: the terminal one of its selection) and
    # those the caller asks for
    held = ({only} if only is not None else set(graph.terminal())) | set(keep or ())
    run = RunState(graph, store, out, executor, force, progress, selected, held, foreign)
    try:
        with progress_to(progress):
            _execute(run, selected, cycles, write_outputs, prepare)
    except BaseException as e:
        # the same command resumes into this folder
        if isinstance(e, KeyboardInterrupt) and write_outputs:
            run_folder.write_interrupted_summary(graph, run, run_id, str(graph.doc.path), out)
        lease.close()
        raise
    finally:
        _release(run, out, own_executor)
    result = _result(run, run_id, selected, write_outputs, lease)
    _prune(store, budget, result)
    result.values, result.item_ids = _terminal_values(graph, run, selected)
    result.state = run
    result.terminal = [n for n in selected if n in run.keep]
    result.seconds = time.perf_counter() - t0
    return result


def _lease(executor: Any, store: ArtifactStore | None, out: Path) -> contextlib.ExitStack:
    """What the run holds while it runs: no prune or clear takes a cache entry from under it."""
    if hasattr(executor, "check_shared"):  # a cluster: its workers read and write our files
        executor.check_shared([out] + ([store.root] if store is not None else []))
    lease = contextlib.ExitStack()
    if store is not None:
        lease.enter_context(in_use(store.root))
    return lease


def _selection(graph: Graph, only: str | None, from_node: str | None) -> tuple[list[str], set[str]]:
    """The nodes to run (``--only``: it and its upstream) and those to recompute (``--from``: it and
    its downstream); ConfigError naming the closest node for a name the graph does not have."""
    for flag, name in (("--only", only), ("--from", from_node)):
        if name is not None and name not in graph.nodes:
            raise ConfigError(
                f"{flag} {name}: no such node in {graph.doc.path.name}",
                None,
                None,
                did_you_mean(name, graph.nodes, "nodes are"),
            )
    wanted = graph.upstream(only) | {only} if only is not None else set(graph.order)
    force = graph.downstream(from_node) | {from_node} if from_node is not None else set()
    return [n for n in graph.order if n in wanted], force


def _open_store(
    doc: Any, cache_dir: str | Path | None, use_cache: bool
) -> tuple[ArtifactStore | None, int]:
    """The run's artifact store (None: ``--no-cache``) and the cache's budget in bytes (0: none)."""
    store = ArtifactStore(cache_dir or project_cache_dir(doc.directory)) if use_cache else None
    return store, project.budget_bytes(doc.directory) if store is not None else 0


def _execute(
    run: RunState,
    selected: list[str],
    cycles: Any,
    write_outputs: bool,
    prepare: Sequence[Callable[[], Any]],
) -> None:
    """The selected nodes, node by node or a streamed region at a time (or the caller's
    ``cycles``)."""
    if cycles is not None:
        cycles(run, selected)
        return
    units = _units(run, selected)
    heads = {u.source: u for u in units if not isinstance(u, str) and u.source}
    for k, unit in enumerate(units):
        if isinstance(unit, str):
            if unit in heads:  # the pool makes its items while this process runs the head
                ahead.start_ahead(run, heads[unit])
            run.run_node(run.g.nodes[unit])
            continue
        if hasattr(run.executor, "start"):  # a local pool: this process only waits
            _prepare_ahead(
                [run.g.nodes[u].spec for u in units[k + 1 :] if isinstance(u, str)], prepare
            )
        streaming.run_region(run, unit, write_outputs)


def _release(run: RunState, out: Path, own_executor: bool) -> None:
    """What the run holds, let go of whatever happened: items made ahead, open resources, our
    pool."""
    ahead.stop_all_ahead(run)
    if (out / ahead.AHEAD_DIR).exists():
        shutil.rmtree(out / ahead.AHEAD_DIR, ignore_errors=True)
    close_resources(run.resources)
    if own_executor:
        run.executor.close()
    if run.store is not None:
        run.store.files.save()


def _result(
    run: RunState,
    run_id: str,
    selected: list[str],
    write_outputs: bool,
    lease: contextlib.ExitStack,
) -> RunResult:
    """The run's result, its folder written (then the cache lease released)."""
    for name in run.g.order:
        if name not in selected:
            run.reports[name].status = "not selected"
    store = run.store
    result = RunResult(
        run_id,
        str(run.g.doc.path),
        run.out_dir,
        run.reports,
        0.0,
        {},
        {},
        run.failures(),
        notes=list(store.notes) if store is not None else [],
    )
    try:
        if write_outputs:
            run_folder.write_run_outputs(run.g, run, result, selected)
    finally:
        lease.close()
    return result


def _prune(store: ArtifactStore | None, budget: int, result: RunResult) -> None:
    """Keep the cache within its budget: only a run that stored something can have grown it past the
    budget (and not while another run uses the cache: the last one to end prunes)."""
    if store is None or not budget or not store.writable or not store.stored_bytes():
        return
    with contextlib.suppress(OSError, CacheBusy):
        n, freed = store.prune(budget)
        if n:
            result.notes.append(
                f"cache over its {budget / 1e9:g} GB budget: removed {n} least recently used "
                f"{'entry' if n == 1 else 'entries'} ({freed / 1e6:.0f} MB)"
            )


_PREPARED: set[str] = set()  # node types whose prepare() ran (or runs) in this process
# run_graph(prepare=...) functions called in this process
_PREPARED_EXTRA: set[Callable[[], Any]] = set()


def _prepare_ahead(specs: list[Any], extra: Sequence[Callable[[], Any]] = ()) -> None:
    """Call the ``prepare()`` of these node types in a background thread (once per type and
    process), then the ``extra`` functions (once per function and process).

    For the nodes that run in this process after a region whose work is in a pool's processes:
    this process only waits meanwhile, so what they load (a plotting library: ~1 s) is loaded on
    a core that would be idle at the run's end, when they run alone.
    """
    todo = [s.prepare for s in specs if s.prepare is not None and s.name not in _PREPARED]
    _PREPARED.update(s.name for s in specs if s.prepare is not None)
    todo += [f for f in extra if f not in _PREPARED_EXTRA]
    _PREPARED_EXTRA.update(extra)
    if not todo:
        return

    def prepare_all() -> None:
        for fn in todo:
            with contextlib.suppress(Exception):  # optional: the node's own call reports a failure
                fn()

    threading.Thread(target=prepare_all, name="stereograph-prepare", daemon=True).start()


def _units(run: RunState, selected: list[str]) -> list[Any]:
    """The run's steps: nodes, and regions of per-item nodes streamed a chunk of items at a time
    (:mod:`stereograph.core.streaming`); node by node where ``STEREOGRAPH_STREAM=0``."""
    if os.environ.get("STEREOGRAPH_STREAM", "1") == "0":
        return list(selected)
    regions = streaming.plan_regions(run.g, selected, run.producer)
    units = streaming.unit_order(run.g, selected, regions) if regions else None
    if units is None:
        return list(selected)
    for reg in regions:
        run.stream(reg.nodes, reg.source)
    return units


class _LazyValues(Mapping):
    """Terminal values by ref, each loaded from the cache the first time it is asked for.

    A rerun with nothing changed then loads nothing that nobody reads (a caller that asks for
    ``result.outputs(...)`` gets the value as before)."""

    def __init__(self, run: RunState, refs: list[Ref]):
        self._run, self._refs, self._got = run, dict.fromkeys(refs), {}

    def __contains__(self, ref: object) -> bool:
        return ref in self._refs

    def __iter__(self):
        return iter(self._refs)

    def __len__(self) -> int:
        return len(self._refs)

    def __getitem__(self, ref: Ref) -> Any:
        if ref not in self._refs:
            raise KeyError(ref)
        if ref not in self._got:
            self._got[ref] = self._run.get(ref)
        return self._got[ref]


def _terminal_values(graph: Graph, run: RunState, selected: list[str]) -> tuple[dict, dict]:
    refs: list[Ref] = []
    items = {}
    for name in selected:
        inst = graph.nodes[name]
        if name not in run.keep and not any(o.save for o in inst.spec.outputs.values()):
            continue
        if run.reports[name].status in ("failed", "skipped"):
            continue
        for out, decl in inst.spec.outputs.items():
            if name not in run.keep and not decl.save:
                continue
            if graph.is_collection(name, out):
                ids = run.items_of(name, out)
                items[(name, out)] = ids
                refs += [(name, out, i) for i in ids]
            elif run.has_value((name, out, None)):
                refs.append((name, out, None))
    return _LazyValues(run, refs), items


def run_pipeline(path: str | Path, overrides: list[str] | None = None, **kwargs: Any) -> RunResult:
    """Load, validate and run a pipeline file. Keyword arguments as :func:`run_graph`."""

    doc = load_pipeline(path, overrides)
    return run_graph(build_graph(doc), **kwargs)
