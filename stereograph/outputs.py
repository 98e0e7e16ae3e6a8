"""Write a run's results into its output folder, in open formats.

Written on every run, cached or not: every output declared ``Out(save=True)`` and every
output of a terminal node. ``uint8`` images (HxW, HxWx3, HxWx4) become PNG; other values
JSON (arrays as nested lists when small, else a side ``.npz``). A per-item output becomes
one JSON list ``<node>/<output>.json`` of ``{"item": id, ...}`` records, or a folder of
``<node>/<output>/<item>.png`` images. A *file value* -- a dict with ``file_suffix`` (``".ply"``,
``".yml"``) and the file's content, encoded by the node, as ``file_bytes`` (1-D ``uint8`` array) or
``file_text`` (str) -- is written as that file as it is (other keys of the dict are for downstream
nodes only). ``run.json`` summarises the run.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import uuid
from pathlib import Path
from typing import Any

import numpy as np

SMALL_ARRAY = 4096  # elements; larger arrays go to .npz beside the JSON


def is_image(v: Any) -> bool:
    return (isinstance(v, np.ndarray) and v.dtype == np.uint8 and
            (v.ndim == 2 or (v.ndim == 3 and v.shape[2] in (3, 4))) and v.size > 64)


_SUFFIX = re.compile(r"^\.[A-Za-z0-9]{1,10}$")


def is_file_value(v: Any) -> bool:
    """A node-encoded file: ``{"file_suffix": ".ext", "file_bytes": uint8 1-D array | "file_text": str, ...}``."""
    if not (isinstance(v, dict) and isinstance(v.get("file_suffix"), str) and _SUFFIX.match(v["file_suffix"])):
        return False
    content = v.get("file_bytes")
    if isinstance(content, np.ndarray):
        return content.ndim == 1 and content.dtype == np.uint8
    return isinstance(v.get("file_text"), str)


def file_content(v: dict) -> bytes:
    """The bytes of a file value (text is written as UTF-8)."""
    return v["file_bytes"].tobytes() if "file_bytes" in v else v["file_text"].encode()


def to_json(v: Any, big: dict[str, np.ndarray], path: str = "") -> Any:
    if isinstance(v, np.ndarray):
        if v.size <= SMALL_ARRAY:
            return v.tolist()
        big[path or "array"] = v
        return {"npz": path or "array", "shape": list(v.shape), "dtype": str(v.dtype)}
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return v.item()
    if isinstance(v, float) and not np.isfinite(v):
        return None if np.isnan(v) else (1e308 if v > 0 else -1e308)
    if isinstance(v, dict):
        return {str(k): to_json(x, big, f"{path}.{k}" if path else str(k)) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_json(x, big, f"{path}[{i}]") for i, x in enumerate(v)]
    return v


def _write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)  # never a half-written result file


def write_value(path_stem: Path, value: Any) -> list[Path]:
    """Write one value as PNG or JSON (+ .npz for large arrays); returns the files written."""
    import cv2

    if is_file_value(value):
        p = path_stem.with_suffix(value["file_suffix"])
        _write_bytes(p, file_content(value))
        return [p]
    if is_image(value):
        ok, buf = cv2.imencode(".png", value)
        if ok:
            p = path_stem.with_suffix(".png")
            _write_bytes(p, buf.tobytes())
            return [p]
    big: dict[str, np.ndarray] = {}
    data = to_json(value, big)
    files = []
    p = path_stem.with_suffix(".json")
    _write_bytes(p, json.dumps(data, indent=1).encode())
    files.append(p)
    if big:
        import io

        buf = io.BytesIO()
        np.savez_compressed(buf, **{k.replace("/", "_"): a for k, a in big.items()})
        q = path_stem.with_suffix(".npz")
        _write_bytes(q, buf.getvalue())
        files.append(q)
    return files


def write_collection(stem: Path, items: dict[str, Any]) -> list[Path]:
    """Write a per-item output: a folder of PNG images, or one JSON list of records."""
    if not items:
        return write_value(stem, [])
    first = next(iter(items.values()))
    if is_image(first) or is_file_value(first):
        out = []
        for i, v in items.items():
            out += write_value(stem / str(i), v)
        return out
    records = []
    for i, v in items.items():
        records.append({"item": i, **v} if isinstance(v, dict) else {"item": i, "value": v})
    return write_value(stem, records)


def _rendered(store: Any, key: str | None, output: str, stem: Path, produce: Any) -> list[Path]:
    """Write one output, reusing the files rendered for the same artifact on an earlier run.

    Encoding a cached image again is most of a cached run's time; a copy of the PNG is not.
    """
    if store is None or not key or key.startswith("volatile") or "/" in key:
        return produce()
    rdir = store.root / "rendered" / key[:2] / f"{key}-{output}"
    if rdir.is_dir():
        files = []
        for f in sorted(rdir.iterdir()):
            dest = stem.with_suffix(f.suffix)
            dest.parent.mkdir(parents=True, exist_ok=True)
            tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp")
            shutil.copyfile(f, tmp)
            os.replace(tmp, dest)
            files.append(dest)
        if files:
            return files
    files = produce()
    tmp = store.tmp / f"r-{uuid.uuid4().hex}"
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        for f in files:
            shutil.copyfile(f, tmp / f.name)
        rdir.parent.mkdir(parents=True, exist_ok=True)
        os.rename(tmp, rdir)
    except OSError:
        pass  # another run rendered it first
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return files


def prepare_out_dir(out_dir: Path) -> None:
    """Make ``out_dir`` ready for a run: a folder of an earlier run is emptied of what that run
    wrote (so no stale result sits beside new ones); any other non-empty folder is refused."""
    from stereograph.errors import ConfigError

    if not out_dir.exists() or not any(out_dir.iterdir()):
        return
    summary = out_dir / "run.json"
    if not summary.is_file():
        raise ConfigError(f"output folder {out_dir} is not empty and holds no earlier run (no run.json)",
                          hint="choose another --out, or empty that folder")
    try:
        written = [f for n in json.loads(summary.read_text()).get("nodes", []) for f in n.get("files", [])]
    except (OSError, ValueError):
        written = []
    for rel in written:
        p = (out_dir / rel).resolve()
        if out_dir.resolve() in p.parents and p.is_file():
            p.unlink()
    summary.unlink()
    for d in sorted((p for p in out_dir.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
        if not any(d.iterdir()):
            d.rmdir()


def write_run_outputs(graph: Any, run: Any, result: Any, selected: list[str]) -> None:
    """Write saved and terminal outputs plus ``run.json`` into ``result.out_dir``."""
    out_dir: Path = result.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, list[str]] = {}
    terminal = set(graph.terminal())
    for name in selected:
        inst = graph.nodes[name]
        if run.reports[name].status in ("failed", "skipped", "not selected") and not inst.mapped:
            continue
        for out, decl in inst.spec.outputs.items():
            if not (decl.save or name in terminal or name in run.keep):
                continue
            stem = out_dir / name / out
            store = run.store
            try:
                if graph.is_collection(name, out):
                    ids = run.items.get((name, out), [])
                    first = run.get((name, out, ids[0])) if ids else None
                    if ids and is_image(first):  # one file per item: reuse earlier renders
                        files = []
                        for i in ids:
                            files += _rendered(store, run.ref_keys.get((name, out, i)), out, stem / str(i),
                                               lambda r=(name, out, i), p=stem / str(i): write_value(p, run.get(r)))
                    else:
                        files = write_collection(stem, {i: run.get((name, out, i)) for i in ids})
                else:
                    if (name, out, None) not in run.ref_keys and (name, out, None) not in run.mem:
                        continue
                    files = _rendered(store, run.ref_keys.get((name, out, None)), out, stem,
                                      lambda r=(name, out, None), p=stem: write_value(p, run.get(r)))
            except Exception as e:  # an output we cannot write must not lose the others
                run.reports[name].messages.append(f"could not write output '{out}': {e}")
                continue
            written.setdefault(name, []).extend(str(f.relative_to(out_dir)) for f in files)
    summary = {
        "run_id": result.run_id,
        "pipeline": result.pipeline,
        "out_dir": str(out_dir),
        "overrides": list(graph.doc.overrides),
        "ok": result.ok,
        "nodes": [{"node": r.name, "type": r.type, "status": r.status, "seconds": round(r.seconds, 4),
                   "items": r.items, "items_ran": r.items_ran, "items_failed": r.items_failed,
                   "error": r.error, "hint": r.hint, "messages": r.messages, "files": written.get(r.name, []),
                   **({"traceback": r.trace} if r.unexpected and r.trace else {})}
                  for r in run.reports.values()],
        "failed_items": [{"node": n, "item": i, "error": e} for (n, i), e in run.failed_items.items()],
        **({"loop": run.loop_info} if getattr(run, "loop_info", None) else {}),  # stereograph.loop
    }
    _write_bytes(out_dir / "run.json", json.dumps(summary, indent=1).encode())
