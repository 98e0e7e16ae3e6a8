"""``stereograph explain``: for every node, fresh or stale, and why — without running anything.

Keys depend only on provenance (code, params, files, upstream keys), never on values, so they
can be computed before a run. What a node's artifacts were last built from is recorded by each
run (``<cache>/last/``); the difference to now is the reason a node is stale.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stereograph.core.api import NodeError
from stereograph.core.cache import ArtifactStore
from stereograph.core.executors import SerialExecutor
from stereograph.core.graph import Graph
from stereograph.core.project import cache_dir as project_cache_dir
from stereograph.core.run_state import RunState


@dataclass
class Verdict:
    node: str
    type: str
    fresh: bool
    reasons: list[str] = field(default_factory=list)


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(d, dict):
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: d}


def _diff(old: dict[str, Any], new: dict[str, Any], root: Path) -> list[str]:
    reasons = []
    if old.get("type") != new["type"]:
        reasons.append(f"type changed: {old.get('type')} -> {new['type']}")
        return reasons
    if old.get("version") != new["version"]:
        reasons.append(f"node version changed: {old.get('version')} -> {new['version']}")
    po, pn = _flat(old.get("params", {})), _flat(new["params"])
    for k in sorted(set(po) | set(pn)):
        if po.get(k, "<unset>") != pn.get(k, "<unset>"):
            reasons.append(
                f"param {k} changed: {po.get(k, '<unset>')!r} -> {pn.get(k, '<unset>')!r}"
            )
    if old.get("code") != new["code"]:
        fo, fn = old.get("code_files", {}), new.get("code_files", {})
        changed = [f for f in sorted(set(fo) | set(fn)) if fo.get(f) != fn.get(f)]
        names = [_rel(f, root) for f in changed] or ["(its module)"]
        reasons.append("source code changed: " + ", ".join(names))
    fo, fn = old.get("files", {}), new["files"]
    changed = [f for f in sorted(set(fo) | set(fn)) if fo.get(f) != fn.get(f)]
    if changed:
        more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
        reasons.append(
            "input files changed: " + ", ".join(_rel(f, root) for f in changed[:3]) + more
        )
    return reasons


def _rel(path: str, root: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(root.resolve()))
    except ValueError:
        return path


def explain(graph: Graph, cache_dir: str | Path | None = None) -> list[Verdict]:
    """Say, per node, whether a run now would reuse its artifacts, and why not.

    A node is fresh when every entry a run would look up is in the store; the reasons a stale
    node gives are what changed since its last run (params, code, files, type, upstream).
    """
    store = ArtifactStore(cache_dir or project_cache_dir(graph.doc.directory))
    run = RunState(graph, store, Path("."), SerialExecutor(), set(), None)
    root = Path.cwd()
    verdicts: list[Verdict] = []
    stale: set[str] = set()
    retrying: dict[str, list[str]] = {}  # node -> the items it tries again (failed in its last run)
    # outputs whose keys (or items) are known only after their node runs
    unknown: set[tuple[str, str]] = set()
    for name in graph.order:
        inst = graph.nodes[name]
        base = run.node_components(inst)
        last = store.last(run.pipeline_id, name)
        computable = not any(wire in unknown for wire in inst.inputs.values())
        got = _look_up(run, store, inst, base, last) if computable else _Lookup(False)
        cacheable = inst.spec.cacheable
        fresh = got.computable and not got.missing and not got.retried and cacheable
        v = Verdict(name, inst.type, fresh)
        own = _diff(last, {**base, "code_files": run.code_digests(inst.type)}, root) if last else []
        if got.retried:
            retrying[name] = got.retried
        if v.fresh:
            v.reasons += _fresh_reasons(own, [a for a in graph.upstream(name) if a in retrying])
        elif got.computable and not got.missing and cacheable:
            v.reasons.append(_retry_reason(got, (last or {}).get("failed") or {}))
        else:
            stale.add(name)
            up = [s for s in graph.dag.predecessors(name) if s in stale]
            v.reasons += _stale_reasons(cacheable, own, up, got, bool(last))
            unknown.update(
                (name, out)
                for out, o in inst.spec.outputs.items()
                if not got.computable or not cacheable or o.collection
            )
        verdicts.append(v)
    return verdicts


@dataclass
class _Lookup:
    """What keying a node's entries now found: whether they could be keyed, how many there are,
    how many the store lacks, and the items a run would try again."""

    computable: bool
    n_entries: int = 0
    missing: int = 0
    retried: list[str] = field(default_factory=list)


def _look_up(run: RunState, store: ArtifactStore, inst: Any, base: dict, last: Any) -> _Lookup:
    """Key every entry a run would look up, as it would, and find each in the store."""
    # entries the last run looked up under these very keys and did not keep: items that failed
    # or were dropped. A run tries them again; predicted as failing again (their downstream
    # entries then stay as they are), and said so.
    tried_before = set((last or {}).get("keys") or ())
    failed_before: dict[str, str] = (last or {}).get("failed") or {}
    entries = run.item_ids(inst) if inst.mapped else [None]
    if run.producer(inst):  # its items are entries of their own (items=)
        try:
            entries += run.produced_ids(inst)
        except NodeError:
            return _Lookup(False)
    got = _Lookup(True, len(entries))
    lost = run.lost_items(inst)
    for item in entries:
        try:
            key = run.entry_key(base, run.input_refs(inst, item), item, lost)
        except KeyError:
            got.computable = False
            break
        run.expect_entry(inst, item, key)
        manifest = store.complete(key) if inst.spec.cacheable else None
        if manifest is not None:
            run.adopt_cached(inst, item, key, manifest)
            run.expect_items(inst, item)
        elif key in tried_before and inst.spec.cacheable and item is not None:
            got.retried.append(item)
            if item in failed_before:  # (else dropped: simply absent downstream)
                run.expect_failure(inst, item, failed_before[item])
        else:
            got.missing += 1
            run.expect_missing(inst, item, key)  # (the key a run would store it under)
    return got


def _fresh_reasons(own: list[str], retrying_upstream: list[str]) -> list[str]:
    reasons = ["cached by an earlier run with these settings"] if own else []
    if retrying_upstream:
        reasons.append(
            "cached -- unless the items "
            + ", ".join(f"'{a}'" for a in retrying_upstream)
            + " tries again succeed this time"
        )
    return reasons


def _retry_reason(got: _Lookup, failed_before: dict[str, str]) -> str:
    def names(items: list[str]) -> str:
        return ", ".join(items[:5]) + (f" and {len(items) - 5} more" if len(items) > 5 else "")

    was_failed = [i for i in got.retried if i in failed_before]
    others = [i for i in got.retried if i not in failed_before]
    said = ([f"{names(was_failed)} failed"] if was_failed else []) + (
        [f"{names(others)} dropped (or pruned since)"] if others else []
    )
    return (
        f"{len(got.retried)} of {got.n_entries} entries the last run looked up with these "
        f"same inputs are not in the cache ({'; '.join(said)}): tried again; what depends on "
        "them stays cached if they fail again"
    )


def _stale_reasons(
    cacheable: bool, own: list[str], up: list[str], got: _Lookup, ran_before: bool
) -> list[str]:
    reasons = (
        [] if cacheable else ["never cached (it has side effects or live input): runs every time"]
    )
    reasons += own
    if up:
        reasons.append(
            "its input changes: upstream " + ", ".join(f"'{s}'" for s in up) + " will run"
        )
    if not reasons:
        reasons.append(
            f"{got.missing} of {got.n_entries} cache entries are missing (cleared, or never "
            "computed with these inputs)"
            if ran_before
            else "not computed yet with these settings"
        )
    return reasons
