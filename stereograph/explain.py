"""``stereograph explain``: for every node, fresh or stale, and why — without running anything.

Keys depend only on provenance (code, params, files, upstream keys), never on values, so they
can be computed before a run. What a node's artifacts were last built from is recorded by each
run (``<cache>/last/``); the difference to now is the reason a node is stale.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stereograph.cache import ArtifactStore
from stereograph.graph import Graph
from stereograph.runner import SerialExecutor, _Run, default_cache_dir


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
            reasons.append(f"param {k} changed: {po.get(k, '<unset>')!r} -> {pn.get(k, '<unset>')!r}")
    if old.get("code") != new["code"]:
        fo, fn = old.get("code_files", {}), new.get("code_files", {})
        changed = [f for f in sorted(set(fo) | set(fn)) if fo.get(f) != fn.get(f)]
        names = [_rel(f, root) for f in changed] or ["(its module)"]
        reasons.append("source code changed: " + ", ".join(names))
    fo, fn = old.get("files", {}), new["files"]
    changed = [f for f in sorted(set(fo) | set(fn)) if fo.get(f) != fn.get(f)]
    if changed:
        more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
        reasons.append("input files changed: " + ", ".join(_rel(f, root) for f in changed[:3]) + more)
    return reasons


def _rel(path: str, root: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(root.resolve()))
    except ValueError:
        return path


def explain(graph: Graph, cache_dir: str | Path | None = None) -> list[Verdict]:
    """Say, per node, whether a run now would reuse its artifacts, and why not."""
    store = ArtifactStore(cache_dir or default_cache_dir(graph.doc))
    run = _Run(graph, store, Path("."), SerialExecutor(), set(), None)
    root = Path.cwd()
    verdicts: list[Verdict] = []
    stale: set[str] = set()
    unknown_items: set[str] = set()
    for name in graph.order:
        inst = graph.nodes[name]
        v = Verdict(name, inst.type, True)
        base = run.node_components(inst)
        base_rec = {**base, "code_files": run.code_files.get(inst.type, {})}
        last = store.last(run.pipeline_id, name)
        if not inst.spec.cacheable:
            v.fresh = False
            v.reasons.append("never cached (it has side effects or live input): runs every time")
        if last is None:
            v.fresh = False
            v.reasons.append("no record of an earlier run of this node")
        else:
            own = _diff(last, base_rec, root)
            if own:
                v.fresh = False
                v.reasons += own
        up_stale = [s for s in graph.dag.predecessors(name) if s in stale]
        if up_stale:
            v.fresh = False
            v.reasons.append("its input changes: upstream " + ", ".join(f"'{s}'" for s in up_stale) + " is stale")
        if any(s in unknown_items for s in graph.dag.predecessors(name)):
            unknown_items.add(name)
        elif v.fresh or not up_stale:
            # keys can be computed: are all entries in the store?
            entries = run.item_ids(inst) if inst.mapped else [None]
            missing = 0
            for item in entries:
                try:
                    key = run.entry_key(base, run.input_refs(inst, item), item)
                except KeyError:
                    missing = -1
                    break
                run.keys[(name, item)] = key
                if store.has(key):
                    run.adopt_cached(inst, item, key)
                    if inst.mapped:
                        for out in inst.spec.outputs:
                            run.items.setdefault((name, out), []).append(item)
                else:
                    missing += 1
            if missing == -1:
                unknown_items.add(name)
                v.fresh = False
            elif missing:
                v.fresh = False
                if not v.reasons:
                    v.reasons.append(f"{missing} of {len(entries)} cache entries are missing "
                                     "(cleared, or never computed with these inputs)")
            if missing and any(o.collection for o in inst.spec.outputs.values()):
                unknown_items.add(name)  # its items are known only once it has run
        if not v.fresh:
            stale.add(name)
        verdicts.append(v)
    return verdicts
