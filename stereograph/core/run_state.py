"""The state of one run: what each node's entries are, where their values are, what happened.

:class:`RunState` keeps its tables (keys, values, items, failures) to itself; the runner,
streaming, outputs, explain, loop and replay go through its operations: key an entry
(:meth:`~RunState.entry_key`), look up (:meth:`~RunState.get`), store
(:meth:`~RunState.store_result`), fail an item, release. Two bases in modules of their own hold
its other operations on the same tables: running a node (:mod:`stereograph.core.node_run`) and
a streamed part of a run (:mod:`stereograph.core.part_run`). What it fills: the shapes of
:mod:`stereograph.core.run_result`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereograph.core.api import NodeError
from stereograph.core.cache import ArtifactStore, CorruptEntry, NotStored
from stereograph.core.calls import Task, execute
from stereograph.core.code_keys import code_hash
from stereograph.core.codecs import content_key, jpeg_roundtrip, read_written_image
from stereograph.core.digests import hash_json
from stereograph.core.errors import ConfigError
from stereograph.core.node_run import NodeRuns
from stereograph.core.part_run import PartRuns
from stereograph.core.run_result import NodeReport, Ref, is_memory_key, memory_key

# (not imported at run time: a replayed rerun runs a node without NetworkX or YAML)
if TYPE_CHECKING:
    from stereograph.core.graph import Graph, NodeInstance


class RunState(NodeRuns, PartRuns):
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
        self._items: dict[tuple[str, str], list[str]] = {}  # collection output -> ok item ids
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
            img = read_written_image(files)  # written to the run folder as its item finished
            if img is None:
                raise NodeError(
                    f"the image written to {files[0]} can no longer be read",
                    hint="run again (the run folder was changed while the run went on)",
                )
            return img
        key = self._ref_keys[ref]
        if is_memory_key(key):  # held in memory only, and let go of
            raise NodeError(f"a value of '{node}' is no longer held (it was kept in memory only)")
        try:
            entry = self.store.load(key)  # type: ignore[union-attr]
        except NotStored:  # kept as a manifest only: computing it again is the cheaper read
            return self._recomputed(ref, item, store=False)
        except CorruptEntry as e:
            self.reports[node].messages.append(
                f"cache entry {key[:12]} was corrupt ({e}); recomputed"
            )
            self.store.delete(key)  # type: ignore[union-attr]
            # (an item of a collection, or its index, is in the node's one entry: entry item None)
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
                ikey = content_key(v) if key else memory_key(inst.name, name, i)
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
            self._ref_keys[(inst.name, name, item)] = key or memory_key(inst.name, item)
        for name, v in single.items():
            if name not in colls:
                self._mem[(inst.name, name, item)] = v
                self._ref_keys[(inst.name, name, item)] = key or memory_key(inst.name, item)
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
            self._ref_keys[ref] = key or memory_key(inst.name, name, item)
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
        only); never a live node's (uncacheable, or a loop's): a camera grabs, an arm moves."""
        inst = self.g.nodes[node]
        if not inst.spec.cacheable or node in self.memory_only:
            raise NodeError(
                f"a value of live node '{node}' is no longer held: it is not run again for it",
                hint="run again; if this comes back, report it with the run's run.json",
            )
        refs = self.input_refs(inst, item)
        res = execute(self.task(inst, item, self.inputs_for(refs)))
        if not res.ok:
            raise NodeError(
                f"recomputing a cache entry of '{node}' failed: {res.error}", hint=res.hint
            )
        self.store_result(inst, item, self._keys.get((node, item)), res.outputs or {}, save=store)

    def item_outputs(self, inst: NodeInstance, item: str | None) -> list[str]:
        """The outputs an entry of this node adds one item to."""
        if item is None:
            return []
        if inst.mapped:
            return list(inst.spec.outputs)
        return [n for n, o in inst.spec.outputs.items() if o.collection]

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
