"""The state of one run: what each node's entries are, where their values are, what happened.

:class:`RunState` keeps its tables (keys, values, items, failures) to itself; the runner,
streaming, outputs, explain, loop and replay go through its operations: key an entry
(:meth:`~RunState.entry_key`), look up (:meth:`~RunState.get`), store
(:meth:`~RunState.store_result`), fail an item, release, run a node; for a streamed region, run
a part of the run (:meth:`~RunState.for_part`, :meth:`~RunState.records`) and take it in
(:meth:`~RunState.absorb`, :meth:`~RunState.settle_member`). What it fills: the shapes of
:mod:`stereograph.core.run_result`.
"""

from __future__ import annotations

import contextlib
import time
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereograph.core.api import NodeError, RunContext
from stereograph.core.cache import ArtifactStore, CorruptEntry, NotStored
from stereograph.core.calls import Task, TaskResult, execute
from stereograph.core.code_keys import code_hash
from stereograph.core.codecs import content_key, jpeg_roundtrip
from stereograph.core.digests import hash_json
from stereograph.core.errors import ConfigError
from stereograph.core.executors import SerialExecutor, lost_as_failed, progress_advance
from stereograph.core.run_result import NodeReport, PartRecords, Ref

# (not imported at run time: a replayed rerun runs a node without NetworkX or YAML)
if TYPE_CHECKING:
    from stereograph.core.graph import Graph, NodeInstance

NO_ITEMS = "no items to process (upstream produced none)"
_HERE_SERIAL = SerialExecutor()  # a node with one entry runs here, not in the pool


class RunState:
    def __init__(
        self,
        graph: Graph,
        store: ArtifactStore | None,
        out_dir: Path,
        executor: Any,
        force: set[str],
        progress: Any,
        selected: Iterable[str] | None = None,
        keep: Iterable[str] | None = None,
        foreign: dict[str, tuple[int, int, int]] | None = None,
    ):
        self.g, self.store, self.out_dir, self.executor = graph, store, out_dir, executor
        self.force, self.progress = force, progress
        self._keys: dict[tuple[str, str | None], str] = {}  # (node, item) -> entry key
        self._ref_keys: dict[Ref, str] = {}  # ref -> key of the entry holding it
        self._mem: dict[Ref, Any] = {}
        # collection output -> item ids (ok ones)
        self._items: dict[tuple[str, str], list[str]] = {}
        self._failed_items: dict[tuple[str, str], str] = {}  # (node, item) -> message
        # the table reads in run order
        self.reports = {n: NodeReport(n, graph.nodes[n].type) for n in graph.order}
        self.pipeline_id = hash_json(str(graph.doc.path))
        self._code: dict[str, str] = {}
        self._code_files: dict[str, dict[str, str]] = {}
        self._remaining_consumers = {n: set(graph.consumers(n)) for n in graph.nodes}
        # the nodes whose values the run's result holds (default: the terminal ones)
        self.keep = set(graph.terminal() if keep is None else keep)
        # RunContext.resource objects, closed when the run ends
        self.resources: dict[str, Any] = {}
        # nodes whose results stay in memory (see stereograph.app.loop)
        self.memory_only: set[str] = set()
        self._ref_ids: dict[Ref, str] = {}  # ref -> content key of a produced item (see ident)
        self._declared: dict[str, list[str]] = {}  # item-producing node -> the item ids it declared
        self._deferred: set[str] = set()  # producers whose items a streamed region makes
        # (node, out) -> item -> files
        self._streamed: dict[tuple[str, str], dict[str, list[Path]]] = {}
        # a part of a run (stereograph.core.streaming): records nothing
        self.sub = False
        self._streaming: set[str] = set()  # per-item nodes run in streamed regions
        self.selected: set[str] = set(graph.nodes if selected is None else selected)
        self._summary: dict[str, Any] = {}  # what callers add to run.json (a loop's cycles)
        # files in out_dir before the run (prepare_out_dir)
        self.foreign: dict[str, tuple[int, int, int]] = dict(foreign or {})

    # ---- keys

    def node_components(self, inst: NodeInstance) -> dict[str, Any]:
        """What, besides inputs, determines this node's artifacts."""
        if inst.type not in self._code:
            index = self.store.files if self.store is not None else None
            self._code[inst.type], self._code_files[inst.type] = code_hash(inst.spec.fn, index)
        try:
            params = inst.params.model_dump(mode="json")
        except Exception as e:
            raise ConfigError(
                f"a parameter value cannot be hashed for the cache: {e}",
                self.g.doc.where("nodes", inst.name, "params"),
                inst.name,
                "use plain numbers, strings, lists and mappings",
            ) from None
        files = {}
        if inst.spec.reads is not None:
            paths = inst.spec.reads(inst.params, self.g.doc.directory)
            for p in paths:
                files[str(p)] = self.store.files.digest(Path(p)) if self.store else "nocache"
        return {
            "type": inst.type,
            "version": inst.spec.version,
            "code": self._code[inst.type],
            "params": params,
            "files": files,
        }

    def input_refs(self, inst: NodeInstance, item: str | None) -> dict[str, Any]:
        """For each input port: a ref, a list of (item, ref) for a gather, or None (unwired)."""
        refs: dict[str, Any] = {}
        for port, (src, out) in inst.inputs.items():
            coll = self.g.is_collection(src, out)
            if inst.spec.inputs[port].gather:
                refs[port] = [(i, (src, out, i)) for i in self._items.get((src, out), [])]
            elif coll:
                refs[port] = (src, out, item)
            else:
                refs[port] = (src, out, None)
        for port in inst.spec.inputs:
            if port not in refs:
                refs[port] = None
        return refs

    def entry_key(
        self,
        base: dict[str, Any],
        refs: dict[str, Any],
        item: str | None,
        lost: dict[str, dict[str, str]] | None = None,
    ) -> str:
        ins = {}
        for port, r in refs.items():
            if r is None:
                ins[port] = None
            elif isinstance(r, list):
                ins[port] = hash_json([[i, self.ident(rr), rr[1]] for i, rr in r])
            else:
                ins[port] = [self.ident(r), r[1]]
        # what a gathering node was told it lost is part of what it made (none: the key as before)
        return hash_json({**base, "inputs": ins, "item": item, **({"lost": lost} if lost else {})})

    def lost_items(self, inst: NodeInstance) -> dict[str, dict[str, str]]:
        """For each gathering port: ``{item: "node: why"}`` of the items that failed at or upstream
        of the wired node, and so are not in the collection it gathers (:attr:`RunContext.lost`)."""
        out: dict[str, dict[str, str]] = {}
        for port, (src, o) in inst.inputs.items():
            if not inst.spec.inputs[port].gather or not self._failed_items:
                continue
            chain = {src} | self.g.upstream(src)
            present = set(self._items.get((src, o), []))
            lost: dict[str, str] = {}
            for (n, i), why in self._failed_items.items():
                if i is not None and n in chain and i not in present and i not in lost:
                    lost[i] = f"{n}: {why}"
            if lost:
                out[port] = dict(sorted(lost.items()))
        return out

    def ident(self, ref: Ref) -> str:
        """What a downstream key says of an input: its content key where known (an item produced
        by a source is content-addressed, so an unchanged item keeps its downstream cached)."""
        return self._ref_ids.get(ref) or self._ref_keys[ref]

    def producer(self, inst: NodeInstance) -> bool:
        """The node produces its collections item by item (declared ``items=``)."""
        return inst.spec.items is not None and not inst.mapped and inst.spec.wants_ctx

    # ---- values

    def get(self, ref: Ref) -> Any:
        if ref in self._mem:
            return self._mem[ref]
        node, out, item = ref
        files = self._streamed.get((node, out), {}).get(item)  # type: ignore[arg-type]
        if files and (self.store is None or ref not in self._ref_keys):
            return _read_back(files)  # an image written to the run folder as its item finished
        key = self._ref_keys[ref]
        try:
            entry = self.store.load(key)  # type: ignore[union-attr]
        except NotStored:  # kept as a manifest only: computing it again is the cheaper read
            return self._recomputed(ref, item, store=False)
        except CorruptEntry as e:
            self.reports[node].messages.append(
                f"cache entry {key[:12]} was corrupt ({e}); recomputed"
            )
            self.store.delete(key)  # type: ignore[union-attr]
            # an item of a collection (or its index) comes from the one entry of the node that
            # yields it
            inst = self.g.nodes[node]
            whole = inst.spec.outputs[out].collection and not self.producer(inst)
            return self._recomputed(ref, None if whole else item)
        for o, v in entry.items():
            self._mem[(node, o, item)] = v
        return self._mem[ref]

    def _recomputed(self, ref: Ref, entry_item: str | None, store: bool = True) -> Any:
        """``ref``'s value, its entry computed again (see :meth:`recompute`)."""
        node, out, item = ref
        self.recompute(node, entry_item, store=store)
        if ref not in self._mem:
            raise NodeError(
                f"recomputing a cache entry of '{node}' no longer gives '{out}'"
                + (f" for item '{item}'" if item is not None else ""),
                hint="run again with --from " + node,
            ) from None  # (called while handling the load's exception: not its cause)
        return self._mem[ref]

    def inputs_for(self, refs: dict[str, Any]) -> dict[str, Any]:
        vals = {}
        for port, r in refs.items():
            if r is None:
                vals[port] = None
            elif isinstance(r, list):
                vals[port] = {i: self.get(rr) for i, rr in r}
            else:
                vals[port] = self.get(r)
        return vals

    def task(
        self,
        inst: NodeInstance,
        item: str | None,
        values: dict[str, Any],
        remote: bool | None = None,
        lost: dict[str, dict[str, str]] | None = None,
    ) -> Task:
        # a params model may come from a plugin module another process has not imported yet
        remote = self.executor.remote if remote is None else remote
        params = inst.params.model_dump() if remote else inst.params
        return Task(
            inst.type,
            list(self.g.doc.plugins),
            params,
            values,
            inst.name,
            item,
            str(self.out_dir),
            str(self.g.doc.directory),
            self.input_types(inst),
            None if remote else self.resources,
            self.producer(inst),
            dict(lost or {}),
        )

    def input_types(self, inst: NodeInstance) -> dict[str, str]:
        """Port -> declared type of the output wired to it (for nodes accepting alternatives)."""
        return {
            port: self.g.nodes[src].spec.outputs[out].type
            for port, (src, out) in inst.inputs.items()
        }

    def store_result(
        self,
        inst: NodeInstance,
        item: str | None,
        key: str | None,
        out: dict[str, Any],
        messages: list[str] | None = None,
        seconds: float | None = None,
        save: bool = True,
    ) -> None:
        """Keep a computed entry's outputs in memory and in the store; split collections into items.

        ``seconds`` (what computing took) lets the store keep a manifest only when recomputing is
        cheaper than reading back (:meth:`ArtifactStore.save`); never for an output the run folder
        gets, nor for collections (their items are content-addressed entries of their own).
        """
        if self.producer(inst) and item is not None:
            self._store_item(inst, item, key, out, messages)
            return
        delivered = inst.name in self.keep or self._saves(inst.name)
        if delivered or any(o.collection for o in inst.spec.outputs.values()):
            seconds = None
        # lossy outputs (pictures for people): stored as JPEG, read as decoded
        encoded: dict[str, bytes] = {}
        for name, o in inst.spec.outputs.items():
            jpeg = jpeg_roundtrip(out.get(name)) if o.lossy and not o.collection else None
            if jpeg is not None:
                out = {**out, name: jpeg[1]}
                encoded[name] = jpeg[0]
        single, colls = self._split_collections(inst, item, key, out)
        if save and self.store is not None and key is not None:
            # collection indexes in the manifest too: a rerun learns the items without loading the
            # entry (which may hold big values beside them, such as calibration views)
            indexes = {n: single[n] for n in colls}
            self.store.save(
                key,
                single,
                {
                    "type": inst.type,
                    "node": inst.name,
                    "item": item,
                    "messages": list(messages or []),
                    "indexes": indexes,
                    "indexes_digest": hash_json(indexes),
                },
                compute_seconds=seconds,
                **({"encoded": encoded} if encoded else {}),
            )

    def _split_collections(
        self, inst: NodeInstance, item: str | None, key: str | None, out: dict[str, Any]
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Keep an entry's values in memory, each collection as content-addressed items (stored
        on their own) under an index; returns ``(what the entry stores, the collections)``."""
        single, colls = {}, {}
        for name, val in out.items():
            if inst.spec.outputs[name].collection:
                if not isinstance(val, dict):
                    raise NodeError(
                        f"output '{name}' must be a mapping {{item_id: value}} (it is a collection)"
                    )
                colls[name] = {str(k): v for k, v in val.items()}
            else:
                single[name] = val
        for name, items in colls.items():
            ids = list(items)
            self._items[(inst.name, name)] = ids
            ikeys = []
            for i, v in items.items():
                # items are content-addressed: a source change that leaves an item as it was
                # (one image added to a folder) leaves that item's downstream cached
                ikey = content_key(v) if key else f"{inst.name}/{name}/{i}"
                ikeys.append(ikey)
                self._ref_keys[(inst.name, name, i)] = ikey
                self._mem[(inst.name, name, i)] = v
                if self.store is not None and key is not None and not self.store.has(ikey):
                    self.store.save(
                        ikey, {name: v}, {"type": inst.type, "node": inst.name, "item": i}
                    )
            single[name] = {"__items__": ids, "__keys__": ikeys}
            # the index too, so that a recompute (a corrupt entry) serves it as a load would
            self._mem[(inst.name, name, item)] = single[name]
            self._ref_keys[(inst.name, name, item)] = key or f"{inst.name}/{item}"
        for name, v in single.items():
            if name not in colls:
                self._mem[(inst.name, name, item)] = v
                self._ref_keys[(inst.name, name, item)] = key or f"{inst.name}/{item}"
        return single, colls

    def _store_item(
        self,
        inst: NodeInstance,
        item: str,
        key: str | None,
        out: dict[str, Any],
        messages: list[str] | None,
    ) -> None:
        """One item of an item-producing node: stored under its own key, known downstream by its
        content key (as the items of a whole collection are). ``{}`` (the node dropped the item)
        stores nothing."""
        content = {}
        for name, v in out.items():
            ref = (inst.name, name, item)
            self._ref_keys[ref] = key or f"{inst.name}/{name}/{item}"
            self._mem[ref] = v
            if key is not None:
                content[name] = self._ref_ids[ref] = content_key(v)
        if out and self.store is not None and key is not None:
            self.store.save(
                key,
                out,
                {
                    "type": inst.type,
                    "node": inst.name,
                    "item": item,
                    "messages": list(messages or []),
                    "content": content,
                },
            )

    def adopt_cached(
        self, inst: NodeInstance, item: str | None, key: str, manifest: dict[str, Any] | None = None
    ) -> None:
        """Register a cached entry's refs without loading big values (collections: load the index).

        ``manifest`` is the one the cache lookup already read, if any (saves reading it again).
        """
        if manifest is None and self.store is not None:
            manifest = self.store.meta(key)
        meta = (manifest or {}).get("meta", {})
        # warnings the node gave when it ran
        self.reports[inst.name].messages += meta.get("messages", [])
        if self.producer(inst) and item is not None:
            content = meta.get("content")
            for name, ck in content.items() if isinstance(content, dict) else []:
                if name in inst.spec.outputs and isinstance(ck, str):
                    self._ref_keys[(inst.name, name, item)] = key
                    self._ref_ids[(inst.name, name, item)] = ck
            return
        for name, o in inst.spec.outputs.items():
            if o.collection and self.producer(inst):
                continue  # produced item by item: not in this entry
            self._ref_keys[(inst.name, name, item)] = key
            if o.collection:
                indexes = meta.get("indexes")
                # (a damaged manifest must not name wrong items: its digest decides, else the entry
                # is read)
                index = (
                    indexes.get(name)
                    if isinstance(indexes, dict)
                    and hash_json(indexes) == meta.get("indexes_digest")
                    else None
                )
                if not (
                    isinstance(index, dict)
                    and isinstance(index.get("__items__"), list)
                    and isinstance(index.get("__keys__"), list)
                    and len(index["__items__"]) == len(index["__keys__"])
                ):
                    # an entry from before indexes were kept there
                    index = self.get((inst.name, name, item))
                ids = index["__items__"]
                self._items[(inst.name, name)] = ids
                for i, k in zip(ids, index["__keys__"]):
                    self._ref_keys[(inst.name, name, i)] = k

    def recompute(self, node: str, item: str | None, store: bool = True) -> None:
        """Compute a cached entry's value again (its entry was corrupt, or kept as a manifest
        only)."""
        inst = self.g.nodes[node]
        refs = self.input_refs(inst, item)
        res = execute(self.task(inst, item, self.inputs_for(refs)))
        if not res.ok:
            raise NodeError(
                f"recomputing a cache entry of '{node}' failed: {res.error}", hint=res.hint
            )
        self.store_result(inst, item, self._keys.get((node, item)), res.outputs or {}, save=store)

    # ---- one node

    def upstream_failed(self, inst: NodeInstance) -> str | None:
        for src in self.g.dag.predecessors(inst.name):
            if self.reports[src].status in ("failed", "skipped"):
                return src
        return None

    def item_ids(self, inst: NodeInstance) -> list[str]:
        ids: list[str] | None = None
        for port, (src, out) in inst.inputs.items():
            if self.g.is_collection(src, out) and not inst.spec.inputs[port].gather:
                these = self._items.get((src, out), [])
                ids = list(these) if ids is None else [i for i in ids if i in set(these)]
        return ids or []

    def item_outputs(self, inst: NodeInstance, item: str | None) -> list[str]:
        """The outputs an entry of this node adds one item to."""
        if item is None:
            return []
        if inst.mapped:
            return list(inst.spec.outputs)
        return [n for n, o in inst.spec.outputs.items() if o.collection]

    def produced_ids(self, inst: NodeInstance) -> list[str]:
        """The item ids an item-producing node declares (cheap: no item is produced)."""
        ctx = RunContext(
            inst.name,
            None,
            self.out_dir / inst.name,
            self.g.doc.directory,
            input_types=self.input_types(inst),
            producing_items=True,
        )
        try:
            ids = [str(i) for i in inst.spec.items(inst.params, ctx)]  # type: ignore[misc]
        except (ValueError, RuntimeError, OSError) as e:
            raise NodeError(f"listing its items failed: {e}") from e
        seen: set[str] = set()
        dup = sorted({i for i in ids if i in seen or seen.add(i)})  # type: ignore[func-returns-value]
        if dup:
            raise NodeError(
                f"it declares item ids more than once: {', '.join(dup[:5])}",
                hint="give every item (scene, file) its own id",
            )
        self.reports[inst.name].messages += ctx.messages
        return ids

    def check_produced(self, inst: NodeInstance) -> None:
        """A producer none of whose declared items came out has failed as a whole."""
        rep = self.reports[inst.name]
        ids = self._declared.get(inst.name, [])
        if (
            ids
            and (inst.name, None) not in self._failed_items
            and not any(self._items.get((inst.name, o)) for o in self.item_outputs(inst, ""))
        ):
            why = "; ".join(m for (n, _), m in list(self._failed_items.items()) if n == inst.name)[
                :400
            ] or "; ".join(rep.messages[:5])
            self.fail_item(
                inst,
                None,
                f"none of its {len(ids)} items could be produced" + (f": {why}" if why else ""),
                "fix or remove the inputs these reasons name"
                if why
                else "see the node's messages in run.json",
            )

    def run_node(self, inst: NodeInstance, items: list[str] | None = None) -> None:
        """Run one node: all its entries, or (a part of a streamed run) a producer's ``items``.

        Plan the entries, look each up in the store, compute the rest, store them, report status."""
        rep = self.reports[inst.name]
        t0 = time.perf_counter()
        bad = self.upstream_failed(inst)
        if bad:
            rep.status, rep.error = "skipped", f"upstream node '{bad}' did not finish"
            return
        store_on = self.store is not None and inst.name not in self.memory_only
        base = self.node_components(inst) if store_on else None
        producer = self.producer(inst)
        entries = self._entries(inst, items, producer)
        if entries is None:  # the producer could not say which items it makes
            rep.seconds = time.perf_counter() - t0
            return
        makes_items = inst.mapped or (
            producer and (items is not None or inst.name not in self._deferred)
        )
        for out in self.item_outputs(inst, "") if makes_items else []:
            self._items[(inst.name, out)] = []
        rep.items = (
            len(entries)
            if inst.mapped
            else len(self._declared.get(inst.name, []))
            if producer
            else 0
        )
        if self.progress:  # (a producer's own entry is not one of its items: "13 items", not 14)
            self.progress.node_started(inst.name, sum(self._counted(inst, i) for i in entries))
        cacheable = store_on and inst.spec.cacheable and inst.name not in self.force
        lost = self.lost_items(inst)
        todo = self._look_up(inst, entries, base if store_on else None, cacheable, lost)
        recorded = store_on and not self.sub and not (inst.mapped and inst.name in self._streaming)
        if recorded:
            self.record(inst, base)
        self._compute(inst, todo, lost, store_on, cacheable, producer)
        if makes_items:  # keep the items in source order
            for out in self.item_outputs(inst, ""):
                done = set(self._items[(inst.name, out)])
                self._items[(inst.name, out)] = [i for i in entries if i in done]  # type: ignore[misc]
        if producer and items is None and inst.name not in self._deferred:
            self.check_produced(inst)
        rep.seconds = time.perf_counter() - t0
        rep.items_failed = sum(1 for (n, _) in self._failed_items if n == inst.name)
        if rep.items_failed and recorded:
            self.record(inst, base)  # again: which of its items failed is known now
        rep.status = self.status_of(inst, producer, rep.items_failed, len(entries), bool(todo))
        if inst.mapped and not entries:
            rep.messages.append(NO_ITEMS)
        self.release(inst.name)

    def _entries(
        self, inst: NodeInstance, items: list[str] | None, producer: bool
    ) -> list[str | None] | None:
        """The node's entries: one per item of a per-item node, else one (None); a producer's own
        entry and then its items (unless a streamed region makes them); None if it cannot list
        them."""
        entries: list[str | None] = self.item_ids(inst) if inst.mapped else [None]
        if producer and items is not None:
            return list(items)
        if producer:  # its other outputs, then (unless a streamed region does) its items
            try:
                if inst.name not in self._declared:  # (known already where items are made ahead)
                    self._declared[inst.name] = self.produced_ids(inst)
            except NodeError as e:
                self.fail_item(inst, None, e.message, e.hint)
                return None
            if inst.name not in self._deferred:
                entries += self._declared[inst.name]
        return entries

    def _look_up(
        self,
        inst: NodeInstance,
        entries: list[str | None],
        base: dict[str, Any] | None,
        cacheable: bool,
        lost: dict,
    ) -> list[tuple[str | None, str | None, dict[str, Any]]]:
        """Key every entry and adopt what the store holds; returns the entries still to compute."""
        todo = []
        for item in entries:
            refs = self.input_refs(inst, item)
            key = self.entry_key(base, refs, item, lost) if base is not None else None
            if key is not None:
                self._keys[(inst.name, item)] = key
            manifest = self.store.complete(key) if cacheable else None  # type: ignore[union-attr]
            if manifest is None:
                todo.append((item, key, refs))
                continue
            self.adopt_cached(inst, item, key, manifest)  # type: ignore[arg-type]
            for out in self.item_outputs(inst, item):
                if (inst.name, out, item) in self._ref_keys:
                    self._items[(inst.name, out)].append(item)  # type: ignore[arg-type]
            if self.progress and self._counted(inst, item):
                self.progress.advance(inst.name)
        return todo

    def _compute(
        self,
        inst: NodeInstance,
        todo: list,
        lost: dict,
        store_on: bool,
        cacheable: bool,
        producer: bool,
    ) -> None:
        """Compute the entries the store did not have, and store what they made."""
        # Lock what we compute so a concurrent run waits and then shares the result. A node called
        # once (calibration, a report) runs here: shipping its inputs to a worker would only add
        # copies, and the pool's workers are busy with items (made ahead: streaming.start_ahead).
        ex = (
            self.executor
            if inst.mapped or any(item is not None for item, _, _ in todo)
            else _HERE_SERIAL
        )
        tasks, metas = [], []
        for item, key, refs in todo:
            try:
                values = self.inputs_for(refs)
            except NodeError as e:
                self.fail_item(inst, item, e.message, e.hint)
                self._advance(inst, item, ok=False)
                continue
            tasks.append(self.task(inst, item, values, ex.remote, lost))
            metas.append((item, key))
        volatile = not store_on or not inst.spec.cacheable
        for (item, key), (res, stored) in zip(
            metas, self._run_locked(inst, tasks, metas, cacheable, ex)
        ):
            if res is not None and not res.ok:
                self.fail_item(
                    inst,
                    item,
                    res.error or "failed",
                    res.hint,
                    res.trace,
                    not res.user_error,
                    res.lasting,
                )
                continue
            if res is None:  # another run computed it while we waited
                self.adopt_cached(inst, item, key)  # type: ignore[arg-type]
            elif not self._keep_result(inst, item, key, res, stored, volatile, store_on, producer):
                continue
            for out in self.item_outputs(inst, item):
                if (inst.name, out, item) in self._ref_keys:  # (not an item the producer dropped)
                    self._items[(inst.name, out)].append(item)  # type: ignore[arg-type]

    def _keep_result(
        self,
        inst: NodeInstance,
        item: str | None,
        key: str | None,
        res: TaskResult,
        stored: bool,
        volatile: bool,
        store_on: bool,
        producer: bool,
    ) -> bool:
        """Store a computed entry's outputs (if the worker did not) and count it; False if they
        cannot be."""
        rep = self.reports[inst.name]
        ok = True
        if volatile:  # (live camera, actuator): a fresh key, so nothing downstream is served stale
            key = f"volatile-{uuid.uuid4().hex}" if store_on else None
        if not stored:
            try:
                self.store_result(inst, item, key, res.outputs or {}, res.messages)
            except (NodeError, TypeError) as e:
                self.fail_item(inst, item, f"its outputs are not storable: {e}", None)
                ok = False
        rep.messages += res.messages
        if inst.mapped or item is not None or not producer:
            rep.items_ran += 1
        return ok

    def status_of(
        self, inst: NodeInstance, producer: bool, n_failed: int, n_entries: int, computed: bool
    ) -> str:
        """ran | cached | failed | partial, from what happened to the node's entries (streamed ones
        too)."""
        if (inst.name, None) in self._failed_items:
            return "failed"
        if (inst.mapped or producer) and n_failed and n_failed < n_entries:
            return "partial"
        if n_failed:
            return "failed"
        return "ran" if computed else "cached"

    def record(self, inst: NodeInstance, base: dict[str, Any] | None) -> None:
        """What this node's entries were made from, for ``explain`` (what changed since)."""
        comps = dict(base or {})
        comps["inputs"] = sorted({src for src in self.g.dag.predecessors(inst.name)})
        comps["upstream"] = {src: self.reports[src].status for src in comps["inputs"]}
        comps["code_files"] = self._code_files.get(inst.type, {})
        comps["keys"] = sorted(k for (n, _), k in self._keys.items() if n == inst.name)[:1000]
        # its items that failed, with why (a gathering node downstream keys on them): explain's
        # guess of the next run, which tries them again, is that they fail again the same way
        comps["failed"] = {
            i: why for (n, i), why in self._failed_items.items() if n == inst.name and i is not None
        }
        self.store.record(self.pipeline_id, inst.name, comps)  # type: ignore[union-attr]

    def _run_locked(
        self, inst: NodeInstance, tasks: list[Task], metas: list, cacheable: bool, ex: Any
    ) -> list:
        """Run tasks; returns (TaskResult or None if another run stored it, stored_already)."""
        if not tasks:
            return []
        if not cacheable:
            return [(r, False) for r in self._advancing(inst, tasks, ex.map(execute, tasks))]
        # Take each entry's lock without blocking: ours to compute; busy ones are being computed
        # by another run right now, so wait for those afterwards and reuse their result.
        results: list[Any] = [None] * len(tasks)
        with contextlib.ExitStack() as stack:
            mine, busy = [], []
            for idx, (_item, key) in enumerate(metas):
                got = stack.enter_context(self.store.lock(key, blocking=False))  # type: ignore[union-attr]
                (mine if got else busy).append(idx)
            ours = [tasks[i] for i in mine]
            for idx, res in zip(mine, self._advancing(inst, ours, ex.map(execute, ours))):
                stored = False
                if res.ok:  # store while still holding the lock
                    item, key = metas[idx]
                    try:
                        self.store_result(
                            inst, item, key, res.outputs or {}, res.messages, res.seconds
                        )
                        stored = True
                    except (NodeError, TypeError) as e:
                        res = TaskResult(False, error=f"its outputs are not storable: {e}")
                results[idx] = (res, stored)
        for idx in busy:
            item, key = metas[idx]
            with self.store.lock(key):  # type: ignore[union-attr]
                if self.store.has(key):  # type: ignore[union-attr]
                    results[idx] = (None, True)
                else:
                    res = execute(tasks[idx])
                    if res.ok:
                        self.store_result(inst, item, key, res.outputs or {}, res.messages)
                    results[idx] = (res, res.ok)
            self._advance(inst, item, ok=results[idx][0] is None or results[idx][0].ok)
        return results

    def _counted(self, inst: NodeInstance, item: str | None) -> bool:
        """Whether an entry counts on the progress display: a producer's whole-node entry does not,
        once its items are known (they are what the display counts)."""
        return not (item is None and self.producer(inst) and self._declared.get(inst.name))

    def _advance(self, inst: NodeInstance, item: str | None, ok: bool = True) -> None:
        if self.progress and self._counted(inst, item):
            progress_advance(self.progress, inst.name, ok)

    def _advancing(
        self, inst: NodeInstance, tasks: list[Task], results: Iterable[TaskResult]
    ) -> Iterable[TaskResult]:
        """The executor's results (in the order of ``tasks``), advancing the progress display as
        each arrives."""
        for task, res in zip(tasks, lost_as_failed(results)):
            self._advance(inst, task.item, res.ok)
            yield res

    def fail_item(
        self,
        inst: NodeInstance,
        item: str | None,
        msg: str,
        hint: str | None,
        trace: str | None = None,
        unexpected: bool = False,
        lasting: bool = False,
    ):
        rep = self.reports[inst.name]
        self._failed_items[(inst.name, item)] = msg  # type: ignore[index]
        rep.lasting |= lasting
        if rep.error is None:
            rep.error = (f"item '{item}': " if item is not None else "") + msg
            rep.hint, rep.trace, rep.unexpected = hint, trace, unexpected
        if item is None:
            rep.status = "failed"

    def release(self, node: str) -> None:
        """Drop in-memory values nobody downstream still needs (Kedro-style)."""
        for src in self.g.dag.predecessors(node):
            self._remaining_consumers[src].discard(node)
            if not self._remaining_consumers[src] and src not in self.keep and not self._saves(src):
                for ref in [r for r in self._mem if r[0] == src]:
                    del self._mem[ref]

    def _saves(self, node: str) -> bool:
        return any(o.save for o in self.g.nodes[node].spec.outputs.values())

    def key_of(self, ref: Ref) -> str | None:
        """The entry key an output reference's value is stored under (None when it has none)."""
        return self._ref_keys.get(ref)

    def entry_key_of(self, node: str, item: str | None = None) -> str | None:
        """The key an entry of ``node`` was looked up under in this run (None when it was not)."""
        return self._keys.get((node, item))

    def used_keys(self) -> set[str]:
        """Every entry key this run looked up or stored under."""
        return {k for k in [*self._keys.values(), *self._ref_keys.values()] if isinstance(k, str)}

    @property
    def any_item_failed(self) -> bool:
        """Some item of some node failed in this run."""
        return bool(self._failed_items)

    def code_digests(self, node_type: str | None = None) -> dict[str, str]:
        """Every code file the entry keys (of ``node_type``'s nodes, or all) were computed from,
        with its digest."""
        if node_type is not None:
            return dict(self._code_files.get(node_type, {}))
        return {f: d for files in self._code_files.values() for f, d in files.items()}

    def items_of(self, node: str, out: str) -> list[str]:
        """The items a collection output holds in this run, in order."""
        return list(self._items.get((node, out), []))

    def expect_entry(self, inst: NodeInstance, item: str | None, key: str) -> None:
        """Note the key an entry of ``inst`` will be looked up under (what ``explain`` predicts)."""
        self._keys[(inst.name, item)] = key

    def expect_failure(self, inst: NodeInstance, item: str, why: str) -> None:
        """Predict that ``item`` of ``inst`` fails again, as it did in the last run
        (``explain``)."""
        self._failed_items[(inst.name, item)] = why

    def expect_missing(self, inst: NodeInstance, item: str | None, key: str) -> None:
        """Predict that an entry is computed and stored under ``key``: its items reach downstream,
        and downstream keys follow from it (``explain``)."""
        for out, o in inst.spec.outputs.items():
            if not o.collection:
                self._ref_keys[(inst.name, out, item)] = key
        self.expect_items(inst, item)

    def expect_items(self, inst: NodeInstance, item: str | None) -> None:
        """The item lists a found or predicted entry of ``inst`` adds ``item`` to."""
        for out in self.item_outputs(inst, item):
            if inst.mapped or (inst.name, out, item) in self._ref_keys:
                self._items.setdefault((inst.name, out), []).append(item)  # type: ignore[arg-type]

    # ---- parts of a run: streamed regions (stereograph.core.streaming)

    @classmethod
    def for_part(
        cls,
        graph: Graph,
        store: ArtifactStore | None,
        out_dir: Path,
        force: set[str],
        code: tuple[dict, dict],
        statuses: dict[str, str],
        keep: set[str],
        keys: dict[Ref, tuple[str, str | None]],
        values: dict[Ref, Any],
        collections: dict[tuple[str, str], list[str]],
        members: set[str],
        back: set[str],
    ) -> RunState:
        """A run of a chunk of items through ``members``, fed the outside values: ``keys`` (ref ->
        (entry key, content key)) of all, ``values`` of those the chunk brought (the others are
        read from the store where needed); the nodes in ``back`` keep their values until the chunk
        hands them back. It records nothing."""
        run = cls(graph, store, out_dir, SerialExecutor(), set(force), None, keep=keep)
        run.sub = True
        run._code, run._code_files = dict(code[0]), dict(code[1])
        for name, status in statuses.items():
            run.reports[name].status = status
        for ref, (key, ident) in keys.items():
            run._ref_keys[ref] = key
            if ident:
                run._ref_ids[ref] = ident
        run._mem.update(values)
        run._items.update({coll: list(ids) for coll, ids in collections.items()})
        run._remaining_consumers = {n: set(graph.consumers(n)) & members for n in graph.nodes}
        for n in back:  # read outside the chunk too: held until the chunk returns it
            run._remaining_consumers[n].add("\0outside")
        return run

    def run_part_node(self, inst: NodeInstance, executor: Any, items: list[str] | None) -> None:
        """(A part of a run) run a node of the chunk: its source for ``items``, or a member. A node
        failing for all of the chunk's items is partial: the other chunks' items go on."""
        self.executor = executor
        if items is not None:
            self.declare_items(inst.name, items)
        self.run_node(inst, items=items)
        rep = self.reports[inst.name]
        if rep.status == "failed" and (inst.name, None) not in self._failed_items:
            rep.status = "partial"

    def records(self, inside: set[str], values: dict, files: dict) -> PartRecords:
        """(A part of a run) what it made, of the nodes ``inside`` the part."""
        return PartRecords(
            reports={n: self.reports[n] for n in inside},
            items={k: v for k, v in self._items.items() if k[0] in inside},
            failed={k: v for k, v in self._failed_items.items() if k[0] in inside},
            ref_keys={r: k for r, k in self._ref_keys.items() if r[0] in inside},
            ref_ids={r: k for r, k in self._ref_ids.items() if r[0] in inside},
            keys={k: v for k, v in self._keys.items() if k[0] in inside},
            values=values,
            files=files,
            messages={
                n: r.messages for n, r in self.reports.items() if n not in inside and r.messages
            },
        )

    def absorb(self, part: PartRecords, source: str | None, skipped: dict[str, str]) -> None:
        """Take in what a part made as if its nodes had run here; ``skipped`` collects the nodes a
        part skipped, with why."""
        for n, r in part.reports.items():
            rep = self.reports[n]
            rep.seconds += r.seconds
            if n != source:
                rep.items += r.items
            rep.items_ran += r.items_ran
            # (a chunk whose items were all dropped upstream says NO_ITEMS; the region says it
            # if true)
            rep.messages += [m for m in r.messages if m not in rep.messages and m != NO_ITEMS]
            if r.status == "skipped":
                skipped.setdefault(n, r.error or "upstream did not finish")
            elif rep.error is None and r.error:
                rep.error, rep.hint, rep.trace, rep.unexpected = (
                    r.error,
                    r.hint,
                    r.trace,
                    r.unexpected,
                )
        for n, msgs in part.messages.items():
            self.reports[n].messages += [m for m in msgs if m not in self.reports[n].messages]
        for k, got in part.items.items():
            self._items.setdefault(k, []).extend(got)
        self._failed_items.update(part.failed)
        self._ref_keys.update(part.ref_keys)
        self._ref_ids.update(part.ref_ids)
        self._keys.update(part.keys)
        self._mem.update(part.values)
        for k, by_item in part.files.items():
            got = {i: [Path(f) for f in fs] for i, fs in by_item.items()}
            self._streamed.setdefault(k, {}).update(got)

    def start_region(self, nodes: Iterable[str], source: str | None) -> list[str]:
        """Empty the item lists a region fills; returns the items it iterates over, in order: the
        source's, or those of the collections it reads from outside."""
        inside = set(nodes) | ({source} if source else set())
        for n in nodes:
            for o in self.g.nodes[n].spec.outputs:
                self._items[(n, o)] = []
        if source:
            for o in self.item_outputs(self.g.nodes[source], ""):
                self._items[(source, o)] = []
            ok = self.reports[source].status not in ("failed", "skipped")
            return list(self._declared.get(source, [])) if ok else []
        seen: dict[str, None] = {}
        for n in nodes:
            inst = self.g.nodes[n]
            for port, (s, o) in inst.inputs.items():
                if (
                    s not in inside
                    and self.g.is_collection(s, o)
                    and not inst.spec.inputs[port].gather
                ):
                    seen.update(dict.fromkeys(self._items.get((s, o), [])))
        return list(seen)

    def order_items(self, nodes: set[str], ids: list[str]) -> None:
        """Put the item lists of ``nodes`` in the order of ``ids`` (chunks finish in any order)."""
        order = {i: k for k, i in enumerate(ids)}
        for (n, o), got in list(self._items.items()):
            if n in nodes:
                self._items[(n, o)] = sorted(
                    dict.fromkeys(got), key=lambda i: order.get(i, len(order))
                )

    def settle_source(self, source: str) -> None:
        """A region's source: its items checked and counted, its status, its record (explain)."""
        src, rep = self.g.nodes[source], self.reports[source]
        self.check_produced(src)
        rep.items_failed = sum(1 for (n, i) in self._failed_items if n == source and i is not None)
        if (source, None) in self._failed_items:
            rep.status = "failed"
        elif rep.items_failed:
            rep.status = "partial"
        elif rep.items_ran:
            rep.status = "ran"
        if self.store is not None and source not in self.memory_only:
            self.record(src, self.node_components(src))  # now with its items' keys

    def settle_member(self, n: str, skipped: dict[str, str], base: dict | None) -> None:
        """A region member's status from its items, and its record for ``explain``."""
        inst, rep = self.g.nodes[n], self.reports[n]
        rep.items_failed = sum(1 for (m, _) in self._failed_items if m == n)
        bad = self.upstream_failed(inst)
        if n in skipped or bad:  # (an upstream node that failed as a whole: no item got here)
            rep.status, rep.error = (
                "skipped",
                skipped.get(n) or f"upstream node '{bad}' did not finish",
            )
            return
        rep.status = self.status_of(inst, False, rep.items_failed, rep.items, bool(rep.items_ran))
        if not rep.items:
            rep.messages.append(NO_ITEMS)
        if self.store is not None and n not in self.memory_only:
            self.record(inst, base)

    def skip_blocked(self, members: list[str]) -> bool:
        """Whether every member of a region waits on a node outside it that failed or was skipped
        (directly, or through a member before it); then each is skipped, as a node-by-node run
        would, and released."""
        blocked: dict[str, str] = {}
        for n in members:  # (in topological order)
            preds = self.g.dag.predecessors(n)
            bad = self.upstream_failed(self.g.nodes[n]) or next(
                (p for p in preds if p in blocked), None
            )
            if bad is None:
                return False
            blocked[n] = bad
        for n in members:
            rep = self.reports[n]
            rep.status, rep.error = "skipped", f"upstream node '{blocked[n]}' did not finish"
            self.release(n)
        return True

    def stream(self, members: Iterable[str], source: str | None) -> None:
        """Have a streamed region run ``members`` (and make ``source``'s items)."""
        self._streaming |= set(members)
        if source:
            self._deferred.add(source)

    def declare_items(self, source: str, ids: list[str]) -> None:
        """The items ``source`` makes (known early: they are being made ahead)."""
        self._declared[source] = list(ids)

    def content_id(self, ref: Ref) -> str | None:
        """The content key of a produced item (None for anything else)."""
        return self._ref_ids.get(ref)

    def held(self, ref: Ref, missing: Any = None) -> Any:
        """The value of ``ref`` if this process holds it in memory, else ``missing``."""
        return self._mem.get(ref, missing)

    def keys_of(self, nodes: set[str]) -> list[tuple[Ref, str]]:
        """``(ref, entry key)`` of every value of ``nodes`` known in this run."""
        return [(ref, key) for ref, key in self._ref_keys.items() if ref[0] in nodes]

    def code_snapshot(self) -> tuple[dict[str, str], dict[str, dict[str, str]]]:
        """``(code digest per node type, code files per node type)`` hashed so far."""
        return dict(self._code), dict(self._code_files)

    def failures(self) -> dict[tuple[str, str | None], str]:
        """``{(node, item): why}`` of every failed item (item None: the node as a whole)."""
        return dict(self._failed_items)

    def has_value(self, ref: Ref) -> bool:
        """Whether ``ref`` has a value in this run (in memory or in the store)."""
        return ref in self._ref_keys or ref in self._mem

    def streamed_files(self, node: str, out: str) -> dict[str, list[Path]]:
        """``{item: files}`` of an output a streamed region wrote into the run folder itself."""
        return dict(self._streamed.get((node, out), {}))

    @contextlib.contextmanager
    def cycling(self, live: set[str], held: set[str]) -> Iterator[None]:
        """(A loop) while it lasts, ``live`` nodes keep their values in memory only (never in the
        store) and ``held`` values stay across cycles."""
        self.memory_only, before = set(live), set(self.keep)
        self.keep |= held
        try:
            yield
        finally:
            self.keep = before

    def add_to_summary(self, key: str, value: Any) -> None:
        """Add ``key: value`` to the run's ``run.json``."""
        self._summary[key] = value

    def summary_additions(self) -> dict[str, Any]:
        return dict(self._summary)

    def take_resource(self, key: str) -> Any:
        """Remove and return a resource a node left for the run (None if none)."""
        return self.resources.pop(key, None)

    def forget(self, nodes: Iterable[str]) -> None:
        """Drop the results of ``nodes`` in this run (values, item lists, failures, reports), so
        that they run again: a loop's next cycle."""
        names = set(nodes)
        for n in names:
            self.reports[n] = NodeReport(n, self.g.nodes[n].type)
            self._remaining_consumers[n] = set(self.g.consumers(n))
        for table in (self._mem, self._ref_keys, self._items, self._failed_items):
            for key in [k for k in table if k[0] in names]:
                del table[key]

    def value_of(self, node: str, out: str) -> Any:
        """The value an output of ``node`` holds in memory now: ``{item: value}`` for a collection
        (None when it holds no item), else the value (None when it has none)."""
        if self.g.is_collection(node, out):
            return {
                i: self._mem.get((node, out, i)) for i in self._items.get((node, out), [])
            } or None
        return self._mem.get((node, out, None))


def _read_back(files: list[Path]) -> Any:
    """An item's image as written to the run folder: PNG is lossless (the very array); a lossy
    output's JPEG decodes to the very array too, since every reader of a lossy output gets the
    decoded JPEG."""
    import cv2

    png = next((f for f in files if f.suffix == ".png"), None) or next(
        (f for f in files if f.suffix == ".jpg"), None
    )
    img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED) if png is not None else None
    if img is None:
        raise NodeError(
            f"the image written to {files[0] if files else '?'} can no longer be read",
            hint="run again (the run folder was changed while the run went on)",
        )
    return img
