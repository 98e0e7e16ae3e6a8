"""Streamed regions: the per-item part of a graph, run a chunk of items at a time.

A region (per-item nodes headed by a source's items) takes a chunk of items through all its
nodes in one task -- here, in a worker process or on Dask -- writes their saved images itself and
sends back only what nodes outside need. Images never travel between processes; memory holds a
chunk, not the collection. Public: :func:`plan_regions`, :func:`run_region`. docs/engine.md.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stereograph.core import outputs as outputs_mod
from stereograph.core import registry
from stereograph.core.ahead import AHEAD_DIR, FromFiles, stop_ahead
from stereograph.core.cache import ArtifactStore
from stereograph.core.executors import SerialExecutor, TaskLost, progress_advance
from stereograph.core.run_result import PartRecords, Ref
from stereograph.core.run_state import RunState

_MISSING = "__stereograph_missing__"  # a value left in the cache (a string: it is pickled)


def _missing(value: Any) -> bool:
    return isinstance(value, str) and value == _MISSING


@dataclass
class Region:
    """Per-item nodes run together, item chunk by item chunk."""

    source: str | None  # the item-producing node whose items the region makes, if any
    nodes: list[str] = field(default_factory=list)  # per-item nodes, in run order


def _item_consumers(graph: Any, src: str) -> set[str]:
    return {
        c
        for c in graph.consumers(src)
        if any(s == src and graph.is_collection(s, o) for s, o in graph.nodes[c].inputs.values())
    }


def _needs_items(graph: Any, node: str, src: str) -> bool:
    """Whether ``node`` or anything upstream of it reads ``src``'s items (so it runs after all are
    made)."""
    return bool(({node} | graph.upstream(node)) & _item_consumers(graph, src))


def plan_regions(graph: Any, selected: list[str], producer: Any) -> list[Region]:
    """Group the selected per-item nodes into regions (see the module docstring).

    A per-item node joins the region of its collection inputs when nothing it reads depends on
    that region's items (else it starts a region of its own, fed from the run's memory)."""
    sel = set(selected)
    regions: list[Region] = []
    of: dict[str, Region] = {}
    claimed: set[str] = set()

    def depends(p: str, reg: Region) -> bool:
        heads = set(reg.nodes) | (_item_consumers(graph, reg.source) if reg.source else set())
        return bool(({p} | graph.upstream(p)) & heads)

    for name in graph.order:
        inst = graph.nodes[name]
        if name not in sel or not inst.mapped:
            continue
        colls = [
            (port, s, o)
            for port, (s, o) in inst.inputs.items()
            if graph.is_collection(s, o) and not inst.spec.inputs[port].gather
        ]
        reg = next((of[s] for _p, s, _o in colls if s in of), None)
        ok = reg is not None
        for port, (s, o) in inst.inputs.items():
            if not ok:
                break
            if graph.is_collection(s, o) and not inst.spec.inputs[port].gather:
                ok = s in reg.nodes or s == reg.source
            else:  # read whole: must not wait for the region's items
                ok = (
                    s not in reg.nodes
                    and not (s == reg.source and graph.is_collection(s, o))
                    and not depends(s, reg)
                )
        if not ok:
            src = next(
                (
                    s
                    for _p, s, _o in colls
                    if s in sel and producer(graph.nodes[s]) and s not in claimed
                ),
                None,
            )
            whole = [
                s
                for port, (s, o) in inst.inputs.items()
                if not (graph.is_collection(s, o) and not inst.spec.inputs[port].gather)
            ]
            if src is not None and any(_needs_items(graph, s, src) for s in whole):
                # what it reads whole gathers the source's items: they are made first, not streamed
                src = None
            reg = Region(src)
            if src:
                claimed.add(src)
            regions.append(reg)
        reg.nodes.append(name)
        of[name] = reg
    return regions


def unit_order(graph: Any, selected: list[str], regions: list[Region]) -> list[Any] | None:
    """Selected nodes and regions in an order that runs each after everything it reads
    (None if grouping would need a cycle: then the run goes node by node)."""
    # here, not at import: a replayed rerun imports this module but schedules nothing
    import networkx as nx

    of = {n: k for k, r in enumerate(regions) for n in r.nodes}
    unit = {n: ("r", of[n]) if n in of else ("n", n) for n in selected}
    dag = nx.DiGraph()
    dag.add_nodes_from(set(unit.values()))
    for a, b in graph.dag.edges:
        if a in unit and b in unit and unit[a] != unit[b]:
            dag.add_edge(unit[a], unit[b])
    for k, r in enumerate(regions):
        if r.source in unit:
            dag.add_edge(unit[r.source], ("r", k))
            # a node outside the region that reads the source's items (a gathering node) runs after
            # them
            for c in _item_consumers(graph, r.source) & set(unit):
                if unit[c] != ("r", k):
                    dag.add_edge(("r", k), unit[c])
    if not nx.is_directed_acyclic_graph(dag):
        return None
    pos = {n: i for i, n in enumerate(graph.order)}
    first = {u: min(pos[n] for n in selected if unit[n] == u) for u in dag.nodes}
    return [
        regions[u[1]] if u[0] == "r" else u[1]
        for u in nx.lexicographical_topological_sort(dag, key=lambda u: first[u])
    ]


def chunk_size(n_items: int, workers: int) -> int:
    """Items per task: about four tasks per worker (the last ones balance the load), at most 8
    (what one task holds in memory at once)."""
    return max(1, min(8, math.ceil(n_items / max(1, workers * 4))))


def chunk_bounds(n_items: int, workers: int) -> list[tuple[int, int]]:
    """``[start, end)`` of each task's items: :func:`chunk_size` items, and with several workers
    the last ``2 x workers`` tasks a quarter of that and the very last ``workers`` tasks one item
    each, so that the workers finish together (one worker alone on a last full chunk leaves the
    others idle for up to a chunk's time)."""
    size = chunk_size(n_items, workers)
    small = max(1, size // 4)
    ones = min(n_items, workers) if workers > 1 and small > 1 else 0
    tail = min(n_items - ones, 2 * workers * small) if workers > 1 else 0
    end_big, end_small = n_items - ones - tail, n_items - ones
    bounds = [(k, min(k + size, end_big)) for k in range(0, end_big, size)]
    bounds += [(k, min(k + small, end_small)) for k in range(end_big, end_small, small)]
    return bounds + [(k, k + 1) for k in range(end_small, n_items)]


@dataclass
class RegionTask:
    """What every chunk of a region shares (picklable for the pools)."""

    graph: Any  # the Graph (in this process) or its pickle (for another one)
    plugins: list[str]
    pipeline_dir: str
    region: Region
    statuses: dict[str, str]  # of the nodes outside the region
    code: tuple[dict, dict]  # code digests and code files per node type (RunState.code_snapshot)
    cache_root: str | None
    out_dir: str
    force: set[str]
    # outputs whose item values the run needs back (read outside, kept)
    back: set[tuple[str, str]]
    deliver: set[tuple[str, str]]  # outputs the run folder gets (saved, terminal)
    keep: set[str]  # the run's kept nodes (terminal, --only) in the region
    # the whole (not per-item) outside values: ref -> (key, content key, value or _MISSING)
    whole: dict[Ref, tuple[str, str | None, Any]] = field(default_factory=dict)
    store: Any = None  # the run's own store, when run in its process
    # file of the whole values (sent once per process instead of in every task)
    shared: str | None = None


@dataclass
class Chunk:
    """One task: a chunk of items through a region."""

    task: RegionTask
    items: list[str]
    inputs: dict[Ref, tuple[str, str | None, Any]]  # this chunk's item values, as ``whole``
    # outside collections: (node, out) -> this chunk's ids
    collections: dict[tuple[str, str], list[str]]
    ahead: dict[str, str] = field(default_factory=dict)  # item -> file of an item made ahead


@dataclass
class ChunkResult:
    records: PartRecords
    notes: list[str]
    seconds: float
    stored_bytes: int = 0  # what the task stored in the cache (the run's budget check counts it)


_STORES: dict[str, Any] = {}  # a worker's stores, by root: opened once per process
# a worker's copy of a region's whole inputs, by file: read once per process
_SHARED: dict[str, dict] = {}


def _shared_values(path: str) -> dict:
    if path not in _SHARED:
        _SHARED.clear()  # (one region at a time)
        _SHARED[path] = pickle.loads(Path(path).read_bytes())
    return _SHARED[path]


def run_chunk(chunk: Chunk) -> ChunkResult:
    """Take a chunk of items through its region (see the module docstring); never raises for a
    node's failure (those are item failures in the result)."""
    t0 = time.perf_counter()
    run, store, written0 = _chunk_state(chunk)
    reg, graph = chunk.task.region, run.g
    for name in ([reg.source] if reg.source else []) + list(reg.nodes):
        source = name == reg.source
        ex = FromFiles(chunk.ahead) if source and chunk.ahead else SerialExecutor()
        run.run_part_node(graph.nodes[name], ex, list(chunk.items) if source else None)
    files, values = _chunk_outputs(chunk, run)
    inside = set(reg.nodes) | ({reg.source} if reg.source else set())
    own_store = store is not None and chunk.task.store is None
    return ChunkResult(
        records=run.records(inside, values, files),
        notes=list(store.notes) if own_store else [],
        seconds=time.perf_counter() - t0,
        stored_bytes=store.stored_bytes() - written0 if own_store else 0,
    )


def _chunk_state(chunk: Chunk) -> tuple[RunState, Any, int]:
    """A small run of the chunk's own: the graph (unpickled in another process, after its plugins),
    the store (one per cache per process), the outside values and keys the chunk brought."""
    t, graph = chunk.task, chunk.task.graph
    if isinstance(graph, bytes):  # another process: its plugins' classes must exist to unpickle
        if t.plugins:
            registry.import_plugins(t.plugins, Path(t.pipeline_dir))
        graph = pickle.loads(graph)
    store = t.store
    if store is None and t.cache_root is not None:
        store = _STORES.get(t.cache_root)
        if store is None:
            store = _STORES[t.cache_root] = ArtifactStore(t.cache_root)
    refs = {**t.whole, **chunk.inputs}
    values = dict(_shared_values(t.shared)) if t.shared else {}
    values.update({ref: v for ref, (_k, _i, v) in refs.items() if not _missing(v)})
    run = RunState.for_part(
        graph,
        store,
        Path(t.out_dir),
        t.force,
        t.code,
        t.statuses,
        set(t.keep),
        {ref: (k, i) for ref, (k, i, _v) in refs.items()},
        values,
        chunk.collections,
        set(t.region.nodes),
        {n for n, _ in t.back},
    )
    return run, store, store.stored_bytes() if store is not None else 0


def _chunk_outputs(chunk: Chunk, run: RunState) -> tuple[dict, dict]:
    """``(files, values)``: the images the chunk wrote into the run folder itself, per output and
    item, and the values it sends back (what nodes outside read, and what it could not write)."""
    files: dict[tuple[str, str], dict[str, list[str]]] = {}
    values: dict[Ref, Any] = {}
    t = chunk.task
    for node, out in sorted(t.deliver | t.back):
        ids = run.items_of(node, out)
        written = (node, out) in t.deliver and ids and _writes_images(run, (node, out, ids[0]))
        lossy = run.g.nodes[node].spec.outputs[out].lossy
        for i in ids:
            ref = (node, out, i)
            if written:
                stem = Path(t.out_dir) / node / out / outputs_mod.file_name(i)
                try:
                    paths = outputs_mod.write_rendered(run, ref, stem, lossy)
                    files.setdefault((node, out), {})[i] = [str(p) for p in paths]
                except Exception as e:  # the run folder writes it again, and says why if it cannot
                    run.reports[node].messages.append(
                        f"could not write output '{out}' of item {i}: {e}"
                    )
                    files.get((node, out), {}).pop(i, None)
                    written = False
            held = run.held(ref, _MISSING)
            if not written and not _missing(held):
                values[ref] = held
    return files, values


def _writes_images(run: Any, first: Ref) -> bool:
    """Whether this output goes to the run folder as one image file per item."""
    try:
        return outputs_mod.image_per_item(run, first)
    except Exception:
        return False


def _label(reg: Region) -> str:
    names = ([reg.source] if reg.source else []) + reg.nodes
    return names[0] if len(names) == 1 else f"{names[0]} → {names[-1]}"


def run_region(run: RunState, reg: Region, write_outputs: bool = True) -> None:
    """Run a region for the parent run ``run``: plan its chunks, hand them to the run's executor,
    and take in what comes back as if each node had run."""
    g, members = run.g, reg.nodes
    inside = set(members) | ({reg.source} if reg.source else set())
    if not reg.source and run.skip_blocked(members):
        return  # (said as each node's own skip: no progress line of items that would never run)
    store_on = run.store is not None
    bases = {n: run.node_components(g.nodes[n]) for n in members} if store_on else {}
    ids = run.start_region(members, reg.source)
    chunks = _plan_chunks(run, reg, ids, inside, *_region_outputs(run, inside, write_outputs))
    label = _label(reg)
    if run.progress:
        run.progress.node_started(label, len(ids))
    skipped: dict[str, str] = {}
    _run_chunks(run, reg, chunks, skipped, label)
    run.order_items(inside, ids)
    if reg.source:
        run.settle_source(reg.source)
    for n in members:
        run.settle_member(n, skipped, bases.get(n))
    for n in ([reg.source] if reg.source else []) + members:
        run.release(n)


def _region_outputs(run: Any, inside: set[str], write_outputs: bool) -> tuple[set, set]:
    """``(back, deliver)``: the outputs a chunk sends back (read outside the region, or kept) and
    those it writes into the run folder itself."""
    g, back, deliver = run.g, set(), set()
    terminal = set(g.terminal())
    for n in inside:
        inst = g.nodes[n]
        for o in run.item_outputs(inst, ""):
            if n in run.keep or any(
                c not in inside and c in run.selected and (n, o) in g.nodes[c].inputs.values()
                for c in g.consumers(n)
            ):
                back.add((n, o))
            if inst.spec.outputs[o].save or n in terminal or n in run.keep:
                (deliver if write_outputs else back).add((n, o))
    return back, deliver


def _plan_chunks(
    run: Any, reg: Region, ids: list[str], inside: set[str], back: set, deliver: set
) -> list[Chunk]:
    """The region's items cut into chunks, each with the outside values (or their keys) it reads."""
    import networkx as nx  # (the graph is built: NetworkX is loaded already)

    g, store_on = run.g, run.store is not None
    statuses = {n: r.status for n, r in run.reports.items() if n not in inside}
    workers = max(1, run.executor.workers)
    # The keys of everything upstream of the region's outside inputs go along (values read on
    # need): an outside item kept as a manifest only is recomputed in the chunk from its own inputs.
    outside = {s for n in reg.nodes for (s, _o) in g.nodes[n].inputs.values() if s not in inside}
    upstream = (outside.union(*(nx.ancestors(g.dag, s) for s in outside))) - inside
    inputs, colls = _outside_inputs(run, reg.nodes, inside)
    for ref, key in run.keys_of(upstream):
        inputs.setdefault(ref, (key, run.content_id(ref), _MISSING))
    task = RegionTask(
        g,
        list(g.doc.plugins),
        str(g.doc.directory),
        reg,
        statuses,
        run.code_snapshot(),
        str(run.store.root) if store_on else None,
        str(run.out_dir),
        set(run.force),
        back,
        deliver,
        run.keep & inside,
        whole={ref: v for ref, v in inputs.items() if ref[2] is None},
        store=run.store,
    )
    by_item: dict[str, dict] = {}  # (each chunk takes its items' values: linear in the items)
    for ref, v in inputs.items():
        if ref[2] is not None:
            by_item.setdefault(ref[2], {})[ref] = v
    at = {c: {i: k for k, i in enumerate(items)} for c, items in colls.items()}
    chunks = []
    for k, end in chunk_bounds(len(ids), workers):
        part = ids[k:end]
        mine = {ref: v for i in part for ref, v in by_item.get(i, {}).items()}
        got = {
            c: sorted((i for i in part if i in pos), key=pos.__getitem__) for c, pos in at.items()
        }
        chunks.append(Chunk(task, part, mine, got))
    return chunks


def _outside_inputs(run: Any, members: list[str], inside: set[str]) -> tuple[dict, dict]:
    """``(inputs, collections)`` of a region: every outside value its nodes read, as (key, id,
    value) -- the value itself when this process holds it, else :data:`_MISSING` (read from the
    cache)."""
    g, store_on = run.g, run.store is not None
    inputs: dict[Ref, tuple[str, str | None, Any]] = {}
    colls = {}
    for n in members:
        for s, o in g.nodes[n].inputs.values():
            if s in inside:
                continue
            if g.is_collection(s, o):
                colls[(s, o)] = run.items_of(s, o)
                refs = [(s, o, i) for i in colls[(s, o)]]
            else:
                refs = [(s, o, None)]
            for ref in refs:
                if ref not in inputs:
                    inputs[ref] = (
                        run.key_of(ref) or "",
                        run.content_id(ref),
                        _outside_value(run, ref, store_on),
                    )
    return inputs, colls


def _outside_value(run: Any, ref: Ref, store_on: bool) -> Any:
    held = run.held(ref, _MISSING)
    if not _missing(held):
        return held
    if store_on and run.key_of(ref) is not None:
        return _MISSING  # read from the cache where it is needed
    try:
        return run.get(ref)
    except (KeyError, Exception):
        return _MISSING


def _run_chunks(
    run: Any, reg: Region, chunks: list[Chunk], skipped: dict[str, str], label: str
) -> None:
    """Run the chunks (here or in the pool) and settle each; a chunk whose worker died is run again
    one item per task, so that an item that kills its worker every time is lost alone."""
    first = run.g.nodes[reg.source or reg.nodes[0]]
    local = not run.executor.remote
    made = stop_ahead(run, reg.source)
    for chunk in chunks:
        chunk.ahead = {i: made[i] for i in chunk.items if i in made}
    if not local and run.store is not None and not made and chunks:
        # A rerun finds most items cached: try the first chunk here; if it computed nothing, the
        # others most likely will not either, and need no worker (start-up, copies) at all.
        probe = run_chunk(chunks[0])
        _settle(run, reg, chunks[0], probe, skipped, label, first)
        chunks = chunks[1:]
        local = not any(r.items_ran for r in probe.records.reports.values())
    if not local and chunks:
        _ship(run, chunks[0].task)
    lost: list[Chunk] = []
    for chunk, res in zip(
        chunks, (run.executor if not local else SerialExecutor()).map(run_chunk, chunks)
    ):
        if isinstance(res, TaskLost) and len(chunk.items) > 1:
            lost.append(chunk)  # its worker died: run its items again one per task, below
            continue
        _settle(run, reg, chunk, res, skipped, label, first)
    alone = [
        dataclasses.replace(
            c,
            items=[i],
            collections={k: [j for j in v if j == i] for k, v in c.collections.items()},
        )
        for c in lost
        for i in c.items
    ]
    for chunk, res in zip(alone, run.executor.map(run_chunk, alone)):
        _settle(run, reg, chunk, res, skipped, label, first)


def _ship(run: Any, task: RegionTask) -> None:
    """Make a region's chunks fit for another process: the graph as bytes, no store object, and
    what every chunk reads whole (the rectification and its maps, ~9 MB) once in a file of the run
    folder, read once per worker process, instead of pickled into every task."""
    task.graph, task.store = pickle.dumps(run.g), None
    whole = {ref: v[2] for ref, v in task.whole.items() if not _missing(v[2])}
    if not whole:
        return
    folder = Path(run.out_dir) / AHEAD_DIR
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"whole-{uuid.uuid4().hex}.pkl"
    path.write_bytes(pickle.dumps(whole, protocol=pickle.HIGHEST_PROTOCOL))
    task.shared = str(path)
    task.whole = {
        ref: (v[0], v[1], _MISSING) if ref in whole else v for ref, v in task.whole.items()
    }


def _settle(
    run: Any, reg: Region, chunk: Chunk, res: Any, skipped: dict[str, str], label: str, first: Any
) -> None:

    if isinstance(res, TaskLost):
        failed = set(chunk.items)
        for i in chunk.items:
            run.fail_item(first, i, res.error, res.hint)
    else:
        failed = {i for (_n, i) in res.records.failed if i is not None}
        run.absorb(res.records, reg.source, skipped)
        if run.store is not None:
            run.store.took_in(res.notes, res.stored_bytes)
    if run.progress:
        for i in chunk.items:
            progress_advance(run.progress, label, i not in failed)
