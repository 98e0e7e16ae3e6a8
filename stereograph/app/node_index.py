"""The index behind ``stereograph nodes``: each node type's inputs, outputs and description.

Kept in a file beside the entry-point index (:func:`stereograph.core.registry.index_file`) and
recomputed, importing the node modules, only for node types whose module folder changed.
Public: :func:`summaries`.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
from pathlib import Path

from stereograph.core import registry
from stereograph.core.errors import ConfigError
from stereograph.core.outputs import write_whole


def _module_stamp(value: str) -> list:
    """Size and mtime of a node module's file and of the files beside it (its package's helpers),
    found without importing the module (its parent packages only)."""
    module = value.partition(":")[0].strip()
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError, AttributeError):
        return [module, None]
    if spec is None or not spec.origin:
        return [module, None]
    folder = Path(spec.origin).parent
    stamp = []
    with contextlib.suppress(OSError):
        for f in sorted(folder.glob("*.py")):
            st = f.stat()
            stamp.append([f.name, st.st_size, st.st_mtime_ns])
    return [module, str(folder), stamp]


def summaries() -> dict[str, dict[str, str]]:
    """For ``stereograph nodes``: each node type's ``io`` ("in:Type → out:Type") and
    ``description``, or its ``error``; kept in an index beside the entry-point one and recomputed
    (importing the node modules) only for node types whose module folder changed."""
    eps = registry.entry_points()
    path = registry.index_file().with_name("node-summaries.json")
    try:
        old = json.loads(path.read_text())
        old = old if isinstance(old, dict) else {}
    except (OSError, ValueError):
        old = {}
    stamps: dict[str, list] = {}
    out: dict[str, dict[str, str]] = {}
    changed = False
    for name in registry.names():
        ep = eps.get(name)
        stamp = [ep.value, _module_stamp(ep.value)] if ep is not None else None
        rec = old.get(name)
        if stamp is not None and isinstance(rec, dict) and rec.get("stamp") == stamp:
            out[name] = rec["summary"]
            continue
        try:
            spec = registry.get(name)
            summary = {
                "io": (
                    ", ".join(f"{k}:{v.type}" for k, v in spec.inputs.items())
                    + " → "
                    + ", ".join(f"{k}:{v.type}" for k, v in spec.outputs.items())
                ),
                "description": spec.description,
            }
        except ConfigError as e:
            summary, stamp = {"error": str(e)}, None  # never remembered: the next call tries again
        out[name] = summary
        if stamp is not None:
            stamps[name] = stamp
            changed = True
    if changed:
        index = {
            n: {"stamp": stamps.get(n, (old.get(n) or {}).get("stamp")), "summary": out[n]}
            for n in out
            if n in stamps or isinstance(old.get(n), dict)
        }
        with contextlib.suppress(OSError):  # (only a fast path for the next listing)
            write_whole(path, json.dumps(index).encode())
    return out
