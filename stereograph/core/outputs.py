"""Write a run's results into its output folder, in open formats.

Every ``Out(save=True)`` output and every terminal node's: images as PNG (JPEG when lossy),
other values as JSON (large arrays in ``.npz``), per-item outputs as one JSON list or a folder
of images, file values as the file itself; ``run.json`` summarises the run. docs/engine.md.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import shutil
import sys
import urllib.parse
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereograph.core import hooks
from stereograph.core.errors import ConfigError

if TYPE_CHECKING:
    import numpy as np

SMALL_ARRAY = 4096  # elements; larger arrays go to .npz beside the JSON
# a run.json key only stereograph writes: the folder holds its run (prepare_out_dir)
MARKER = "stereograph_run"
_PLAIN_ID = re.compile(r"^[^\W][\w.-]{0,119}$")


def file_name(item: Any) -> str:
    """An item id as one safe file-name component.

    Item ids come from data (a file name, a scene id in a YAML list), so ``../../x`` or ``/etc``
    must not become a path: ids of letters, digits, ``_ . -`` (not starting with a dot, at most
    120 characters) are kept as they are; any other is percent-encoded (``..%2F..%2Fx``), and a
    long one shortened with a digest. Distinct ids give distinct names.
    """
    text = str(item)
    if _PLAIN_ID.match(text) and ".." not in text:
        return text
    enc = urllib.parse.quote(text, safe="-_").replace(".", "%2E")
    if len(enc) > 120:
        enc = (
            enc[:96]
            + "~"
            + hashlib.blake2b(text.encode("utf-8", "surrogatepass"), digest_size=8).hexdigest()
        )
    return enc or "%00"


def _numpy() -> Any:
    """NumPy if something imported it, else None: then no value is an array (a replayed rerun writes
    its run folder without importing NumPy)."""
    return sys.modules.get("numpy")


def image_shaped(v: Any, channels: tuple[int, ...] = (3, 4)) -> bool:
    """A uint8 array H x W, or H x W x C with C in ``channels``, of any size."""
    np = _numpy()
    return np is not None and (
        isinstance(v, np.ndarray)
        and v.dtype == np.uint8
        and (v.ndim == 2 or (v.ndim == 3 and v.shape[2] in channels))
    )


def is_image(v: Any) -> bool:
    """An image written as PNG (:func:`image_shaped`, more than 64 values: smaller ones are
    data)."""
    return image_shaped(v) and v.size > 64


_SUFFIX = re.compile(r"^\.[A-Za-z0-9]{1,10}$")


def is_file_value(v: Any) -> bool:
    """A node-encoded file: ``{"file_suffix": ".ext", "file_bytes": uint8 1-D array | "file_text":
    str, ...}``."""
    if not (
        isinstance(v, dict)
        and isinstance(v.get("file_suffix"), str)
        and _SUFFIX.match(v["file_suffix"])
    ):
        return False
    np = _numpy()
    content = v.get("file_bytes")
    if np is not None and isinstance(content, np.ndarray):
        return content.ndim == 1 and content.dtype == np.uint8
    return isinstance(v.get("file_text"), str)


def file_content(v: dict) -> bytes:
    """The bytes of a file value (text is written as UTF-8)."""
    return v["file_bytes"].tobytes() if "file_bytes" in v else v["file_text"].encode()


def to_json(v: Any, big: dict[str, np.ndarray], path: str = "") -> Any:
    if v is None or type(v) in _PLAIN:  # most leaves: no NumPy type to ask about
        return v
    np = _numpy()
    if np is not None:
        if isinstance(v, np.ndarray):
            if v.size <= SMALL_ARRAY:
                return v.tolist()
            big[path or "array"] = v
            return {"npz": path or "array", "shape": list(v.shape), "dtype": str(v.dtype)}
        if isinstance(v, (np.floating, np.integer, np.bool_)):
            return v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else (1e308 if v > 0 else -1e308)
    if isinstance(v, dict):
        return {str(k): to_json(x, big, f"{path}.{k}" if path else str(k)) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_json(x, big, f"{path}[{i}]") for i, x in enumerate(v)]
    return v


_PLAIN = (str, int, bool)


def _with_ext(stem: Path, ext: str) -> Path:
    """``stem`` + ``ext`` (not ``with_suffix``: an item id ``scene.001`` keeps its ``.001``)."""
    return stem.with_name(stem.name + ext)


def write_whole(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file beside it: the file is whole or absent
    (an interrupt, a full disk), and no ``.tmp`` is left behind."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)  # never a half-written result file
    except BaseException:
        tmp.unlink(missing_ok=True)  # a full disk must not leave a .tmp behind
        raise


def write_value(path_stem: Path, value: Any, lossy: bool = False) -> list[Path]:
    """Write one value as PNG or JSON (+ .npz for large arrays); returns the files written.
    ``lossy``: an image output declared ``Out(lossy=True)`` (a picture for people) is written as
    JPEG. ``None`` is an output the node did not produce (an overlay switched off): nothing is
    written."""
    if value is None:
        return []
    if lossy:
        from stereograph.core.codecs import jpeg_roundtrip

        jpeg = jpeg_roundtrip(value)
        if jpeg is not None:
            p = _with_ext(path_stem, ".jpg")
            write_whole(p, jpeg[0])
            return [p]
    if is_file_value(value):
        p = path_stem.with_suffix(value["file_suffix"])
        write_whole(p, file_content(value))
        return [p]
    if is_image(value):
        import cv2

        ok, buf = cv2.imencode(".png", value)
        if ok:
            p = _with_ext(path_stem, ".png")
            write_whole(p, buf.tobytes())
            return [p]
    big: dict[str, np.ndarray] = {}
    data = to_json(value, big)
    files = []
    p = _with_ext(path_stem, ".json")
    write_whole(p, json.dumps(data, indent=1).encode())
    files.append(p)
    if big:  # (arrays: NumPy is imported)
        import io

        import numpy as np

        buf = io.BytesIO()
        np.savez_compressed(buf, **{k.replace("/", "_"): a for k, a in big.items()})
        q = _with_ext(path_stem, ".npz")
        write_whole(q, buf.getvalue())
        files.append(q)
    return files


def write_collection(stem: Path, items: dict[str, Any], lossy: bool = False) -> list[Path]:
    """Write a per-item output: a folder of PNG images (JPEG for a ``lossy`` output), or one JSON
    list of records. Items whose value is ``None`` (not produced) are left out; none produced, no
    file."""
    if not items:
        return write_value(stem, [])
    items = {i: v for i, v in items.items() if v is not None}
    if not items:
        return []
    first = next(iter(items.values()))
    if is_image(first) or is_file_value(first):
        out = []
        for i, v in items.items():
            out += write_value(stem / file_name(i), v, lossy)
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
    ready = store.ready_file(key, output)
    # the entry keeps this image as the very PNG (or JPEG) the run folder gets
    if ready is not None:
        dest = _with_ext(stem, ready.suffix)
        _link_or_copy(ready, dest)
        return [dest]
    rdir = store.root / "rendered" / key[:2] / f"{key}-{output}"
    blobs = _verified_render(rdir)
    if blobs:
        files = []
        for name, data in blobs.items():
            dest = _with_ext(stem, Path(name).suffix)
            write_whole(dest, data)
            files.append(dest)
        return files
    if rdir.exists() and store.writable:  # corrupt or unverifiable: render again
        shutil.rmtree(rdir, ignore_errors=True)
    files = produce()
    if not store.writable or store.ready_file(key, output):
        return files  # (an entry stored just now keeps the PNG itself: no second copy)
    tmp = store.tmp / f"r-{uuid.uuid4().hex}"
    try:
        tmp.mkdir(parents=True, exist_ok=True)
        digests = {}
        for f in files:
            data = f.read_bytes()
            (tmp / f.name).write_bytes(data)
            digests[f.name] = hashlib.blake2b(data, digest_size=16).hexdigest()
        (tmp / RENDER_DIGESTS).write_text(json.dumps(digests))  # last: marks the copy complete
        rdir.parent.mkdir(parents=True, exist_ok=True)
        os.rename(tmp, rdir)
    except OSError:
        # another run rendered it first, or the cache cannot take it: the result is written anyway
        pass
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return files


def _link_or_copy(src: Path, dest: Path) -> None:
    """Put ``src`` at ``dest`` as a hard link (no second copy on disk), else as a copy (another
    disk).

    The cache checks its files' digests before any use, so a linked result edited in place is
    detected there, and recomputed, never delivered."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        os.link(src, tmp)
        os.replace(tmp, dest)
    except OSError:
        tmp.unlink(missing_ok=True)
        write_whole(dest, src.read_bytes())


RENDER_DIGESTS = "digests.json"


def _verified_render(rdir: Path) -> dict[str, bytes] | None:
    """The rendered files kept in ``rdir`` if every one matches its recorded digest, else None
    (a flipped byte in a cached PNG must not be delivered as a result)."""
    try:
        digests = json.loads((rdir / RENDER_DIGESTS).read_text())
        if not isinstance(digests, dict) or not digests:
            return None
        blobs = {}
        for name, want in sorted(digests.items()):
            if "/" in name or name.startswith("."):
                return None
            data = (rdir / name).read_bytes()
            if hashlib.blake2b(data, digest_size=16).hexdigest() != want:
                return None
            blobs[name] = data
        return blobs
    except (OSError, ValueError, TypeError, AttributeError):
        return None


def check_folder_path(out: Path) -> Path:
    """Refuse an output folder that is an existing file or lies under one (:class:`ConfigError`);
    returns the nearest existing folder on its path (the folder itself when it exists)."""

    if out.exists() and not out.is_dir():
        raise ConfigError(f"output folder {out} is an existing file", hint="choose another --out")
    probe = out
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError(
            f"output folder {out} cannot be made: {probe} is a file", hint="choose another --out"
        )
    return probe


def prepare_out_dir(out_dir: Path) -> dict[str, tuple[int, int, int]]:
    """Make ``out_dir`` ready for a run.

    A folder that an earlier stereograph run wrote (its ``run.json`` carries the :data:`MARKER` key,
    which only stereograph writes) is emptied of the files that run recorded, and of the sub-folders
    they leave empty, so that no stale result sits beside new ones. Any other non-empty folder is
    refused: another tool's ``run.json`` or a user's files are never deleted.

    Returns
    -------
    dict
        The files left in the folder (a user's, say), relative path -> stamp: what
        :func:`node_files` must not take for a file a node of this run wrote.
    """

    probe = check_folder_path(out_dir)
    if not os.access(probe, os.W_OK | os.X_OK):  # (a read-only file system says so even to root)
        raise ConfigError(
            f"output folder {out_dir} cannot be written: {probe} is not writable",
            hint="choose another --out",
        )
    try:
        if not out_dir.exists() or not any(out_dir.iterdir()):
            return {}
    except OSError as e:
        raise ConfigError(
            f"cannot use output folder {out_dir}: {e.strerror or e}", hint="choose another --out"
        ) from None
    summary = out_dir / "run.json"
    try:
        earlier = json.loads(summary.read_text()) if summary.is_file() else None
        ours = isinstance(earlier, dict) and isinstance(earlier.get(MARKER), dict)
        written = [f for n in earlier.get("nodes", []) for f in n.get("files", [])] if ours else []
    except (OSError, ValueError, AttributeError, TypeError):
        ours, written = False, []
    if not ours:
        raise ConfigError(
            f"output folder {out_dir} is not empty and is not the folder of an earlier "
            "stereograph run (no run.json that stereograph wrote)",
            hint="choose another --out, or empty that folder",
        )
    _clear_earlier_run(out_dir, written)
    return _present(out_dir)


def _clear_earlier_run(out_dir: Path, written: list[Any]) -> None:
    """Delete what an earlier run recorded writing into ``out_dir``, and the folders it leaves
    empty; nothing else."""
    root = out_dir.resolve()
    parents: set[Path] = set()
    for rel in written:
        if not isinstance(rel, str):
            continue
        p = (out_dir / rel).resolve()
        if root in p.parents and p.is_file():
            p.unlink()
            parents.update(q for q in p.parents if root in q.parents)
    (out_dir / "run.json").unlink()
    # written from that run.json (stereograph.app.report)
    (out_dir / "report.html").unlink(missing_ok=True)
    # stereograph never makes symbolic links: one inside the folder was put there since, and writing
    # through it (a node's folder linked elsewhere) would write outside the run's folder
    for dirpath, dirnames, filenames in os.walk(out_dir):  # (does not follow links)
        for name in dirnames + filenames:
            if (Path(dirpath) / name).is_symlink():
                (Path(dirpath) / name).unlink()
    for d in sorted(parents, key=lambda p: -len(p.parts)):  # only folders the run's files were in
        try:
            d.rmdir()
        except OSError:
            pass  # not empty: something else lives there


def _stamp(p: Path) -> tuple[int, int, int]:
    st = p.lstat()
    return st.st_ino, st.st_size, st.st_mtime_ns


def _present(folder: Path) -> dict[str, tuple[int, int, int]]:
    """Every file under ``folder`` (links not followed), relative path -> stamp."""
    found = {}
    for dirpath, _dirs, files in os.walk(folder):
        for f in files:
            p = Path(dirpath) / f
            with contextlib.suppress(OSError):  # (gone meanwhile)
                found[str(p.relative_to(folder))] = _stamp(p)
    return found


def write_run_outputs(graph: Any, run: Any, result: Any, selected: list[str]) -> None:
    """Write saved and terminal outputs plus ``run.json`` into ``result.out_dir``."""
    out_dir: Path = result.out_dir
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(
            f"cannot make output folder {out_dir}: {e.strerror or e}", hint="choose another --out"
        ) from None
    written: dict[str, list[str]] = {}
    terminal = set(graph.terminal())
    for name in selected:
        inst = graph.nodes[name]
        if run.reports[name].status in ("failed", "skipped", "not selected") and not inst.mapped:
            continue
        for out, decl in inst.spec.outputs.items():
            if not (decl.save or name in terminal or name in run.keep):
                continue
            try:
                files = _output_files(graph, run, name, out, decl, out_dir / name / out)
            except Exception as e:  # an output we cannot write must not lose the others ...
                rep = run.reports[name]
                rep.messages.append(f"could not write output '{out}': {e}")
                # ... nor pass for a delivered result
                if isinstance(e, OSError) and rep.error is None:
                    rep.status, rep.error = (
                        "failed",
                        f"could not write output '{out}': {e.strerror or e}",
                    )
                    rep.hint = (
                        "free space on that disk, or choose another --out; the result is cached"
                    )
                continue
            written.setdefault(name, []).extend(str(f.relative_to(out_dir)) for f in files or [])
    add_node_files(out_dir, graph.nodes, written, run.foreign)
    summary = run_summary(
        graph,
        run,
        result.run_id,
        result.pipeline,
        out_dir,
        result.ok,
        list(result.notes),
        written,
    )
    try:
        write_whole(out_dir / "run.json", json.dumps(summary, indent=1).encode())
    except OSError as e:
        raise ConfigError(
            f"cannot write {out_dir / 'run.json'}: {e.strerror or e}",
            hint="free space on that disk, or choose another --out",
        ) from None
    notes = hooks.announce("run_written", out_dir)  # the app's page; never a failed run
    result.notes.extend(notes)


def _output_files(
    graph: Any, run: Any, name: str, out: str, decl: Any, stem: Path
) -> list[Path] | None:
    """Write one output of a node (each item's, for a per-item output); the files, or None for
    nothing."""
    if not graph.is_collection(name, out):
        if not run.has_value((name, out, None)):
            return None
        return write_rendered(run, (name, out, None), stem, decl.lossy)
    ids = run.items_of(name, out)
    streamed = run.streamed_files(name, out)
    # written item by item as each finished (streaming)
    if streamed and all(i in streamed for i in ids):
        return [f for i in ids for f in streamed[i]]
    if not ids and run.reports[name].status in ("failed", "skipped"):
        return None  # (the items that did finish are kept; none is not an empty result)
    if not (ids and image_per_item(run, (name, out, ids[0]))):
        return write_collection(stem, {i: run.get((name, out, i)) for i in ids})
    files = []
    for i in ids:
        files += write_rendered(run, (name, out, i), stem / file_name(i), decl.lossy)
    return files


def image_per_item(run: Any, first: tuple) -> bool:
    """Whether a per-item output goes to the run folder as one image file per item: known from
    its first entry's manifest without loading it, else from the first item's value."""
    if run.store is not None and run.store.ready_file(run.key_of(first) or "", first[1]):
        return True
    return is_image(run.get(first))


def write_rendered(run: Any, ref: tuple, stem: Path, lossy: bool) -> list[Path]:
    """Write the value of ``ref`` (node, output, item) at ``stem`` (:func:`_rendered`)."""
    return _rendered(
        run.store, run.key_of(ref), ref[1], stem, lambda: write_value(stem, run.get(ref), lossy)
    )


def node_files(
    out_dir: Path, name: str, known: set[str], foreign: dict[str, tuple[int, int, int]]
) -> list[str]:
    """Files in the node's folder that it wrote itself (through ``ctx.out_dir``: a failure log,
    say).

    Recorded in ``run.json`` with its outputs (``known``), so that a later run into this folder
    removes them with the rest (:func:`prepare_out_dir`) instead of leaving them beside its own
    results. A file that was there before the run, unchanged (``foreign``, from
    :func:`prepare_out_dir`: a user's notes), is not the run's: recording it would have the next run
    delete what stereograph did not write.
    """
    folder = out_dir / name
    if folder.is_symlink() or not folder.is_dir():
        return []
    found = []
    for rel, stamp in _present(folder).items():
        rel = str(Path(name) / rel)
        if (
            rel not in known
            and not Path(rel).name.startswith(".")
            and foreign.get(rel) != stamp
            and not (out_dir / rel).is_symlink()
        ):  # (.x.tmp: being written; a link: not ours)
            found.append(rel)
    return sorted(found)


def add_node_files(
    out_dir: Path,
    names: Any,
    written: dict[str, list[str]],
    foreign: dict[str, tuple[int, int, int]],
) -> None:
    """Add to ``written`` (node -> files of the run) what each named node wrote into its folder
    itself (:func:`node_files`): a run's, an interrupted run's and a compare variant's ``run.json``
    record it."""
    for name in names:
        extra = node_files(out_dir, name, set(written.get(name, [])), foreign)
        if extra:
            written.setdefault(name, []).extend(extra)


def run_summary(
    graph: Any,
    run: Any,
    run_id: str,
    pipeline: str,
    out_dir: Path,
    ok: bool,
    notes: list[str],
    written: dict[str, list[str]],
) -> dict[str, Any]:
    """``run.json``'s content."""
    return {
        MARKER: {"format": 1, "run_id": run_id},
        "run_id": run_id,
        "pipeline": pipeline,
        "out_dir": str(out_dir),
        "overrides": list(graph.doc.overrides),
        "ok": ok,
        "notes": notes,
        "nodes": [
            {
                "node": r.name,
                "type": r.type,
                "status": r.status,
                "seconds": round(r.seconds, 4),
                "items": r.items,
                "items_ran": r.items_ran,
                "items_failed": r.items_failed,
                "error": r.error,
                "hint": r.hint,
                "messages": r.messages,
                "files": written.get(r.name, []),
                **_wiring(graph, r.name),
                **({"traceback": r.trace} if r.unexpected and r.trace else {}),
            }
            for r in run.reports.values()
        ],
        "failed_items": [
            {"node": n, "item": i, "error": e} for (n, i), e in run.failures().items()
        ],
        # what the caller added (a loop: its cycles)
        **run.summary_additions(),
    }


def write_interrupted_summary(
    graph: Any, run: Any, run_id: str, pipeline: str, out_dir: Path
) -> None:
    """A ``run.json`` for a run stopped by Ctrl-C / SIGTERM: the nodes' states and the files written
    so far (the items streamed into the folder), so that the same command with the same ``--out``
    can reuse the folder -- emptied of those files first -- while the cache resumes the work. Never
    raises."""
    for rep in run.reports.values():
        if rep.status in ("pending", "running"):
            rep.status = "interrupted"
    written: dict[str, list[str]] = {}
    with contextlib.suppress(Exception):
        # the items streamed into the folder so far are files of their nodes' folders
        add_node_files(out_dir, graph.nodes, written, run.foreign)
        notes = ["interrupted: finished nodes and items are cached; the same command resumes"]
        out_dir.mkdir(parents=True, exist_ok=True)
        summary = run_summary(graph, run, run_id, pipeline, out_dir, False, notes, written)
        write_whole(out_dir / "run.json", json.dumps(summary, indent=1).encode())


def _wiring(graph: Any, name: str) -> dict[str, Any]:
    """What report.html needs to draw the graph from run.json alone."""
    inst = graph.nodes.get(name)
    if inst is None:
        return {}
    headline = [o for o, decl in inst.spec.outputs.items() if decl.headline]
    return {
        "mapped": bool(inst.mapped),
        "inputs": {p: [s, o] for p, (s, o) in inst.inputs.items()},
        **({"headline": headline} if headline else {}),
    }
