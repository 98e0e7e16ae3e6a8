"""Items made ahead: a pool makes a region's source items while the run's head still runs.

The head of a run (calibration, rectification) runs serially in this process; meanwhile the
pool's workers make the items of the region that follows, each into a whole-or-absent file of
the run folder's :data:`AHEAD_DIR`, which the region's task then reads instead of making the
item again. Public: :func:`start_ahead`, :func:`stop_ahead`, :func:`stop_all_ahead`,
:class:`FromFiles`.
"""

from __future__ import annotations

import concurrent.futures as cf
import pickle
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stereograph.core import outputs as outputs_mod
from stereograph.core import registry
from stereograph.core.api import NodeError
from stereograph.core.calls import Task, TaskResult, execute
from stereograph.core.executors import SerialExecutor
from stereograph.core.run_state import RunState

AHEAD_DIR = ".stereograph-ahead"  # in the run folder, removed when the run ends
# per run: source -> its items being made ahead (start_ahead), until the region takes them
_AHEAD: weakref.WeakKeyDictionary[RunState, dict[str, Any]] = weakref.WeakKeyDictionary()


@dataclass
class AheadTask:
    """Make some of a source's items while the run's head (calibration, ...) is still running."""

    graph: bytes
    plugins: list[str]
    pipeline_dir: str
    source: str
    items: list[str]
    folder: str
    out_dir: str


def produce_ahead(task: AheadTask) -> list[str]:
    """(In a worker) make the items and leave each in a file of its own; returns those made.

    An item that fails is left to its region task, which makes it again and reports why."""

    if task.plugins:
        registry.import_plugins(task.plugins, Path(task.pipeline_dir))
    graph = pickle.loads(task.graph)
    inst = graph.nodes[task.source]
    done = []
    for i in task.items:
        res = execute(
            Task(
                inst.type,
                list(task.plugins),
                inst.params.model_dump(),
                {},
                inst.name,
                i,
                task.out_dir,
                task.pipeline_dir,
                {},
                None,
                True,
            )
        )
        if not res.ok:
            continue
        made = (res.outputs, res.messages, res.seconds)
        # whole or absent: a cancelled run leaves no half item
        path = Path(task.folder) / f"{outputs_mod.file_name(i)}.pkl"
        outputs_mod.write_whole(path, pickle.dumps(made, protocol=pickle.HIGHEST_PROTOCOL))
        done.append(i)
    return done


def start_ahead(run: Any, reg: Any) -> None:
    """Set the pool making the region's items now, while this process runs the head (the
    source's own part, calibration, rectification): that head is serial, and the workers would
    otherwise wait for it. Only for a process pool (it runs on this machine), only items not
    already cached; the region task takes each item made ahead from its file."""

    ex, inst = run.executor, run.g.nodes[reg.source]
    if not hasattr(ex, "start") or inst.inputs:
        return
    try:
        ids = run.produced_ids(inst)
        run.declare_items(reg.source, ids)
    except NodeError:
        return  # the source's own run says why
    if run.store is not None and inst.spec.cacheable and reg.source not in run.force:
        base = run.node_components(inst)
        refs = run.input_refs(inst, None)
        ids = [i for i in ids if run.store.complete(run.entry_key(base, refs, i)) is None]
    if not ids:
        return
    folder = Path(run.out_dir) / AHEAD_DIR
    folder.mkdir(parents=True, exist_ok=True)
    graph = pickle.dumps(run.g)

    def task(items: list[str]) -> AheadTask:
        return AheadTask(
            graph,
            list(run.g.doc.plugins),
            str(run.g.doc.directory),
            reg.source,
            items,
            str(folder),
            str(run.out_dir),
        )

    # The first item is made here, before the pool's processes start (a pool forks them at its
    # first task): what the node prepares once per process for its items (source.synthetic: the
    # scene plan, the cameras' ray grids, the table's texture and render, ~2 s) is then inherited
    # by every worker instead of being prepared again in each one.
    here: cf.Future = cf.Future()
    here.set_result(produce_ahead(task(ids[:1])))
    later = ex.start(produce_ahead, [task(ids[k : k + 2]) for k in range(1, len(ids), 2)])
    _AHEAD.setdefault(run, {})[reg.source] = ([here, *later], folder, outputs_mod.file_name)


def stop_all_ahead(run: RunState) -> None:
    """Stop whatever is still being made ahead for ``run`` (the run is ending)."""
    for source in list(_AHEAD.get(run, {})):
        stop_ahead(run, source)


def stop_ahead(run: Any, source: str | None) -> dict[str, str]:
    """Cancel the ahead tasks not begun, wait for the others; {item: file} of the items made."""
    got = _AHEAD.get(run, {}).pop(source, None) if source else None
    if got is None:
        return {}
    futures, folder, name = got
    run.executor.stop(futures)
    made: dict[str, str] = {}
    for fut in futures:
        if fut.cancelled() or fut.exception() is not None:
            continue
        for i in fut.result():
            made[i] = str(folder / f"{name(i)}.pkl")
    return made


class FromFiles(SerialExecutor):
    """A region task's executor for its source: an item made ahead is read from its file."""

    def __init__(self, files: dict[str, str]):
        self.files = files

    def map(self, fn: Any, tasks: list[Any]) -> Any:
        for t in tasks:
            path = self.files.get(t.item) if t.producing else None
            if path is None:
                yield fn(t)
                continue
            try:
                outputs, messages, seconds = pickle.loads(Path(path).read_bytes())
                Path(path).unlink(missing_ok=True)
            except (OSError, pickle.UnpicklingError, EOFError, ValueError):
                yield fn(t)  # gone or damaged: make it here
                continue
            yield TaskResult(True, outputs, seconds, messages)
