"""A run's folder: made ready for a run, its results written into it, its ``run.json``.

:func:`prepare_out_dir` empties a folder an earlier run wrote (only the files that run recorded)
and refuses any other non-empty one; :func:`write_run_outputs` writes every saved and terminal
output (through :mod:`stereograph.core.outputs`) and ``run.json``, which records every file the
run wrote; :func:`write_interrupted_summary` does the same for a run stopped part way.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any

from stereograph.core import hooks
from stereograph.core.errors import ConfigError
from stereograph.core.outputs import (
    file_name,
    image_per_item,
    write_collection,
    write_rendered,
    write_whole,
)

# a run.json key only stereograph writes: the folder holds its run (prepare_out_dir)
MARKER = "stereograph_run"


def marker(run_id: str) -> dict[str, Any]:
    """The value of ``run.json``'s :data:`MARKER` key (its format and the run's id)."""
    return {"format": 1, "run_id": run_id}


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
        status = run.reports[name].status
        if status in ("pending", "running", "interrupted"):
            continue  # it did not finish in this run: it has nothing to deliver
        if status in ("failed", "skipped", "not selected") and not inst.mapped:
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
        MARKER: marker(run_id),
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
