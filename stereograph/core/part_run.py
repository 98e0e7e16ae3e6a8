"""Parts of a run: a streamed region's chunk run as a small run of its own, and taken back in.

:class:`PartRuns` is the part of :class:`~stereograph.core.run_state.RunState` that
:mod:`stereograph.core.streaming` calls: make a part (:meth:`~PartRuns.for_part`), run its nodes,
hand back its :class:`~stereograph.core.run_result.PartRecords`, then, in the run, take them in
(:meth:`~PartRuns.absorb`) and settle each node's status. It works on the run state's own
tables, so only ``RunState`` inherits it.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

from stereograph.core.executors import SerialExecutor
from stereograph.core.run_result import NO_ITEMS, PartRecords, Ref

if TYPE_CHECKING:
    from stereograph.core.cache import ArtifactStore
    from stereograph.core.graph import Graph, NodeInstance


class PartRuns:
    """How :class:`~stereograph.core.run_state.RunState` runs a part of a run (its base class)."""

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
    ) -> Self:
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
