"""Running one node of a run: plan its entries, look them up, compute the rest, store, status.

:class:`NodeRuns` is the part of :class:`~stereograph.core.run_state.RunState` that runs a node
(:meth:`~NodeRuns.run_node`; one entry per item of a per-item node). It works on the run state's
own tables, so only ``RunState`` inherits it; entries are computed under the store's lock, so
that concurrent runs share what one of them computes.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from stereograph.core.api import NodeError, RunContext
from stereograph.core.calls import Task, TaskResult, execute
from stereograph.core.executors import SerialExecutor, lost_as_failed, progress_advance
from stereograph.core.run_result import NO_ITEMS, volatile_key

if TYPE_CHECKING:
    from stereograph.core.graph import NodeInstance

_HERE_SERIAL = SerialExecutor()  # a node with one entry runs here, not in the pool


class NodeRuns:
    """How :class:`~stereograph.core.run_state.RunState` runs one node (its base class)."""

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
        # copies, and the pool's workers are busy with items (made ahead: ahead.start_ahead).
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
            key = volatile_key() if store_on else None
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
