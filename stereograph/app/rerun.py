"""Reruns that only look: a ``stereograph run`` with nothing changed, replayed without the graph.

After a clean run the command records a memo in ``<cache>/reruns/<id>/`` (file stamps, entry keys,
hard links to the run folder's files, ``run.json``, what the console showed). The next run of the
same command is replayed from it when its sources, entries, run-folder files and plugins are
unchanged; uncacheable nodes still run for real. Anything else falls back to the ordinary run:
the memo is only a fast path. Public: :func:`replay`, :func:`record`, :func:`forget`,
:func:`fingerprint`. docs/engine.md ("Replayed reruns") has every rule.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from stereograph.core import hooks
from stereograph.core.digests import RACY_NS, file_digest, hash_json
from stereograph.core.run_result import is_lasting_key

FORMAT = 1
MAX_MEMOS = 32  # memos kept per cache (oldest removed first): one per pipeline and --set line
MEMO_DIR = "reruns"
STAMPS = "stamps.json"  # beside memo.json: the stamps its files have now (see _restamp)
# a must-run node's inputs up to this size (as JSON) are kept in its memo
SMALL_INPUTS_BYTES = 4 << 20
_ENGINE_DIR = Path(__file__).resolve().parent


class _Stale(Exception):
    """The memo does not describe what a run would do now: run for real."""


def memo_dir(cache: Path, pipeline: str | Path, overrides: list[str]) -> Path:
    """The memo folder of one command line (pipeline file and ``--set`` overrides, in order)."""
    key = hash_json([FORMAT, str(Path(pipeline).resolve()), list(overrides)])
    return Path(cache) / MEMO_DIR / key[:24]


def _stamp(path: str | Path) -> list[int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]


def fingerprint(pipeline: str | Path) -> list:
    """The folders Python imports from, in order, and their mtimes: installing or removing a package
    changes one (as the entry-point index's fingerprint, with paths made absolute: ``.venv/bin`` and
    ``/work/x/.venv/bin`` are one folder). The pipeline's own folder, and any folder importing a
    plugin put on ``sys.path`` (for the rest of the process: a second run in it would otherwise
    never be replayed), are left out: the files there that count are stamped one by one."""
    from stereograph.core import registry

    out = []
    skip = {str(Path(pipeline).resolve().parent)} | {
        os.path.abspath(p) for p in registry.PLUGIN_PATHS
    }
    for p in sys.path:
        p = os.path.abspath(p or ".")
        if p in skip:
            continue
        try:
            out.append([p, os.stat(p).st_mtime_ns])
        except OSError:
            out.append([p, None])
    return out


def _engine_files() -> list[str]:
    return sorted(str(p) for p in _ENGINE_DIR.glob("*.py"))


# --------------------------------------------------------------------------- record


def record(graph: Any, result: Any, echo: list[list[Any]], sys_path: list | None = None) -> bool:
    """Record the memo of a finished run (see the module docstring); returns whether it did.

    ``echo``: what the console showed of the terminal outputs, as ``[title, kind, text]``, and
    ``["live", node, output]`` where a node that must run shows its value. ``sys_path``: the
    :func:`fingerprint` taken as the command started. Only a run where every node ran or was cached
    is recorded, and only when what the run used is still what is on disk.
    """
    run, doc = result.state, graph.doc
    live = _live_nodes(graph, result)
    if live is None:
        return False
    t_rec = time.time_ns()
    inputs = _unchanged_inputs(graph, run, live)
    if inputs is None or any(
        st is not None and max(st[1], st[2]) > t_rec - RACY_NS for st in inputs.values()
    ):
        return False  # changed a moment ago (mtime or ctime): the next run decides for itself
    live_keys = {run.entry_key_of(n) for n in live}
    entries = sorted(k for k in run.used_keys() if is_lasting_key(k) and k not in live_keys)
    memo: dict[str, Any] = {
        "format": FORMAT,
        "recorded_ns": t_rec,
        "pipeline": str(doc.path),
        "overrides": list(doc.overrides),
        "name": doc.name,
        "pipeline_dir": str(doc.directory),
        "plugins": list(doc.plugins),
        "fingerprint": _now(sys_path, doc.path),
        "inputs": inputs,
        "entries": entries,
        "echo": echo,
        "files": {},
        "summary": json.loads((result.out_dir / "run.json").read_text()),
        "where": {n: str(doc.where("nodes", n)) for n in graph.nodes},
        "upstream": {n: bool(graph.upstream(n)) for n in graph.nodes},
        "live": {n: _live_record(run, graph.nodes[n]) for n in live},
    }
    return _write_memo(run.store, doc, memo, result.out_dir, set(live))


def _live_nodes(graph: Any, result: Any) -> list[str] | None:
    """The nodes a replay must run (uncacheable, or kept in memory by a loop); None when the run
    cannot be replayed: no writable store, not every node ran or was cached, or a live node that
    is not a terminal one-call node with whole values (see _run_live)."""
    run = result.state
    store = run.store
    if store is None or not store.writable or not result.ok or run.any_item_failed or result.notes:
        return None
    if any(r.status not in ("ran", "cached") for r in run.reports.values()):
        return None
    live = [n for n, inst in graph.nodes.items() if not inst.spec.cacheable or n in run.memory_only]
    for n in live:
        inst = graph.nodes[n]
        outputs = inst.spec.outputs.values()
        if inst.mapped or graph.consumers(n) or any(o.collection for o in outputs):
            return None
    return live


def _unchanged_inputs(graph: Any, run: Any, live: list[str]) -> dict[str, list[int] | None] | None:
    """The stamp now of everything the run used (pipeline files, code, the engine, files nodes
    read), when each is still what the run used; None when one changed."""
    from stereograph.core.config import load_pipeline

    doc = graph.doc
    inputs: dict[str, list[int] | None] = {}
    # the pipeline as this run read it: the files' stamps now, and their content now equal to the
    # run's
    config_files = {str(doc.path)} | {
        w.file for w in doc.lines.values() if getattr(w, "file", None)
    }
    for f in sorted(config_files):
        inputs[f] = _stamp(f)
    again = load_pipeline(doc.path, list(doc.overrides))
    if (again.nodes, again.defaults, again.name, again.plugins) != (
        doc.nodes,
        doc.defaults,
        doc.name,
        doc.plugins,
    ):
        return None
    # the code the keys were computed from: each file's digest now equal to the one the run used
    for f, d in run.code_digests().items():
        before = _stamp(f)
        if before is None or file_digest(Path(f)) != d or _stamp(f) != before:
            return None
        inputs[f] = before
    for f in _engine_files():
        inputs[f] = _stamp(f)
    read = _read_files(graph, run.store.files, live)
    return None if read is None else {**inputs, **read}


def _read_files(graph: Any, index: Any, live: list[str]) -> dict[str, list[int] | None] | None:
    """The stamps of the files the nodes read, when the digest the run keyed on belongs to exactly
    these stamps (the store's file index); None when one changed."""
    stamps: dict[str, list[int] | None] = {}
    for n, inst in graph.nodes.items():
        if inst.spec.reads is None or n in live:
            continue
        for p in inst.spec.reads(inst.params, graph.doc.directory):
            rp = str(Path(p).resolve())
            st, rec = _stamp(rp), index.recorded(rp)
            if st is None:
                stamps[rp] = st
                continue
            if rec is None or rec[0] != st:
                return None
            # hashed within a timestamp tick of its mtime: the content now must be what was hashed
            if rec[2] - st[1] < RACY_NS and (file_digest(Path(rp)) != rec[1] or _stamp(rp) != st):
                return None
            stamps[rp] = st
    return stamps


def _write_memo(store: Any, doc: Any, memo: dict, out_dir: Path, live: set[str]) -> bool:
    """Write ``memo`` with hard links to the run folder's files (not the live nodes'), in place of
    the pipeline's old memo; False when it cannot (another disk than the cache, say)."""
    final = memo_dir(store.root, doc.path, list(doc.overrides))
    # the old memo goes first: removing its links changes the ctime of the files the new one stamps
    trash = store.tmp / f"del-{uuid.uuid4().hex}"
    with contextlib.suppress(OSError):
        trash.parent.mkdir(parents=True, exist_ok=True)
        os.rename(final, trash)
    shutil.rmtree(trash, ignore_errors=True)
    tmp = store.tmp / f"memo-{uuid.uuid4().hex}"
    try:
        tmp.mkdir(parents=True)  # (a run that saved no file has no files/ folder to make it)
        for node in memo["summary"]["nodes"]:
            if node["node"] in live:
                continue
            for rel in node.get("files", []):
                src, dest = out_dir / rel, tmp / "files" / rel
                dest.parent.mkdir(parents=True, exist_ok=True)
                # (another disk than the cache: no memo rather than a second copy)
                os.link(src, dest)
                memo["files"][rel] = {
                    "stamp": _stamp(dest),
                    "digest": file_digest(dest),
                    "verified_ns": memo["recorded_ns"],
                }
        (tmp / "memo.json").write_text(json.dumps(memo))
        final.parent.mkdir(parents=True, exist_ok=True)
        os.rename(tmp, final)  # (a concurrent run's memo there first: ours is dropped)
    except OSError:
        return False
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    _trim(final.parent)
    return True


def _now(sys_path: list | None, pipeline: Path) -> list:
    """The fingerprint now, of the folders that were on ``sys.path`` as the command started (the run
    itself may have made the first ``runs/`` in a folder that is on it: that is no package
    change)."""
    now = fingerprint(pipeline)
    if sys_path is None:
        return now
    start = [p for p, _ in sys_path]
    return (
        [e for e in now if e[0] in start]
        if [e[0] for e in now if e[0] in start] == start
        else sys_path
    )


def _key(run: Any, ref: Any) -> str:
    """The entry key of an input: a memo is never recorded with one missing (the caller gives up on
    it)."""
    key = run.key_of(ref)
    if key is None:
        raise KeyError(ref)
    return key


def _live_record(run: Any, inst: Any) -> dict[str, Any]:
    """What running a must-run node again needs: its params as data, and each input's entry key."""
    ports: dict[str, Any] = {}
    for port, r in run.input_refs(inst, None).items():
        if r is None:
            ports[port] = None
        elif isinstance(r, list):  # a gather: {item: value}
            ports[port] = {"gather": [[i, _key(run, rr), rr[1]] for i, rr in r]}
        else:
            ports[port] = {"key": _key(run, r), "output": r[1]}
    rec = {
        "type": inst.type,
        "params": inst.params.model_dump(mode="json"),
        "ports": ports,
        "input_types": run.input_types(inst),
        "outputs": list(inst.spec.outputs),
    }
    # Inputs that are small plain data (an arm, pick plans) are kept in the memo as the cache keeps
    # them (JSON): a replay then reads one file instead of an entry per item.
    from stereograph.core.codecs import encode

    arrays: dict[str, Any] = {}
    with contextlib.suppress(Exception):
        values = encode(run.inputs_for(run.input_refs(inst, None)), arrays)
        if not arrays and len(json.dumps(values)) < SMALL_INPUTS_BYTES:
            rec["values"] = values
    return rec


def _trim(root: Path) -> None:
    """Keep the :data:`MAX_MEMOS` most recently written memos."""
    with contextlib.suppress(OSError):
        dirs = sorted((d for d in root.iterdir() if d.is_dir()), key=lambda d: d.stat().st_mtime)
        for d in dirs[:-MAX_MEMOS]:
            shutil.rmtree(d, ignore_errors=True)


def forget(cache_root: Path) -> None:
    """Drop every memo (pruning removed entries: a memo's links must not keep their files alive)."""
    shutil.rmtree(Path(cache_root) / MEMO_DIR, ignore_errors=True)


# --------------------------------------------------------------------------- replay


@dataclass
class Replayed:
    """A replayed run, shaped for the command line's summary (``reports``, ``run_id``, ``ok``)."""

    run_id: str
    out_dir: Path
    reports: dict[str, Any]
    echo: list[list[Any]]
    where: dict[str, str]
    upstream: dict[str, bool]
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not any(r.status in ("failed", "partial") for r in self.reports.values())


def _report(name: str, type_: str, status: str, **kw: Any) -> SimpleNamespace:
    """A node's line of a replayed run: the attributes of run_result.NodeReport (not imported: it
    brings NumPy and pydantic, which a replay without nodes to run does without)."""
    fields = dict(
        seconds=0.0,
        items=0,
        items_ran=0,
        items_failed=0,
        error=None,
        hint=None,
        trace=None,
        unexpected=False,
        messages=[],
        files=[],
    )
    fields.update(kw)
    return SimpleNamespace(name=name, type=type_, status=status, **fields)


def replay(
    pipeline: str | Path,
    overrides: list[str],
    cache_dir: str | Path | None = None,
    out_dir: str | Path | None = None,
) -> Replayed | None:
    """Replay the run of this command line from its memo, or None when a real run is needed."""
    from stereograph.core import project

    try:
        path = Path(pipeline).resolve()
        if not path.is_file():
            return None
        cache = Path(cache_dir) if cache_dir else project.cache_dir(path.parent)
        mdir = memo_dir(cache, path, overrides)
        memo = json.loads((mdir / "memo.json").read_text())
        if (
            not isinstance(memo, dict)
            or memo.get("format") != FORMAT
            or memo.get("pipeline") != str(path)
            or memo.get("overrides") != list(overrides)
        ):
            return None
        _restamp(memo, mdir)
        live_inputs = _check(memo, mdir, cache)
    except (_Stale, OSError, ValueError, TypeError, KeyError, AttributeError):
        return None
    return _write(memo, mdir, Path(out_dir) if out_dir else None, live_inputs)


def _check(memo: dict[str, Any], mdir: Path, cache: Path) -> dict[str, dict[str, Any]]:
    """Every check of the module docstring; the inputs of the nodes that must run. Writes nothing
    but the "used" marks of the entries."""
    from stereograph.core import registry

    if memo["plugins"] and not registry.PLUGINS_ALLOWED:
        raise _Stale("plugins not allowed")  # (the real run refuses them, with the reason)
    if memo["fingerprint"] != fingerprint(memo["pipeline"]):
        raise _Stale("installed packages changed")
    t_rec = memo["recorded_ns"]
    for f, st in memo["inputs"].items():
        if _stamp(f) != st or (st is not None and max(st[1], st[2]) > t_rec - RACY_NS):
            raise _Stale(f"{f} changed")
    objects = str(cache / "objects")  # (strings, not Paths: a thousand entries)
    for key in memo["entries"]:
        man = f"{objects}/{key[:2]}/{key}/manifest.json"
        try:
            os.utime(man)  # present, and used now (least-recently-used pruning)
        except FileNotFoundError:
            raise _Stale(f"entry {key} is gone") from None
        except OSError:  # a read-only cache: present is enough
            os.stat(man)
    files = str(mdir / "files")
    for rel, rec in memo["files"].items():
        p = f"{files}/{rel}"
        st = _stamp(p)
        if st is None:
            raise _Stale(f"{rel} is gone")
        if st != rec["stamp"] or st[1] > rec["verified_ns"] - RACY_NS:
            if file_digest(p) != rec["digest"]:
                raise _Stale(f"{rel} was edited")
            rec["stamp"], rec["verified_ns"] = st, time.time_ns()
    from stereograph.core.errors import ConfigError

    for spec in memo["live"].values():
        try:  # the module now, before execute's clock starts (a real run imports it at graph time)
            if memo["plugins"]:
                registry.import_plugins(memo["plugins"], Path(memo["pipeline_dir"]))
            registry.get(spec["type"])
        except ConfigError as e:  # the real run reports it as it should
            raise _Stale(str(e)) from None
    return {n: _live_inputs(cache, spec) for n, spec in memo["live"].items()}


def _live_inputs(cache: Path, spec: dict[str, Any]) -> dict[str, Any]:
    """A must-run node's input values, from the memo or loaded from the cache (anything amiss: a
    real run). (The entries they come from were checked present.)"""
    if "values" in spec:
        return spec["values"]
    from stereograph.core.cache import ArtifactStore, CorruptEntry, NotStored

    store = ArtifactStore(cache)
    values: dict[str, Any] = {}
    try:
        for port, p in spec["ports"].items():
            if p is None:
                values[port] = None
            elif "gather" in p:
                values[port] = {i: store.load(k)[o] for i, k, o in p["gather"]}
            else:
                values[port] = store.load(p["key"])[p["output"]]
    except (CorruptEntry, NotStored, KeyError) as e:
        raise _Stale(f"an input of a node that must run does not load: {e}") from None
    return values


def _write(
    memo: dict[str, Any], mdir: Path, out_dir: Path | None, live_inputs: dict[str, dict[str, Any]]
) -> Replayed | None:
    """The run folder: the memo's files linked, the must-run nodes run, run.json and report.html."""
    from stereograph.core import outputs, project, run_folder

    run_id = project.new_run_id()
    out = out_dir or project.runs_dir(memo["pipeline_dir"]) / memo["name"] / run_id
    foreign = run_folder.prepare_out_dir(out)
    if not _link_files(memo, mdir, out):
        return None
    summary = memo["summary"]
    reports: dict[str, SimpleNamespace] = {}
    echo_live: dict[tuple[str, str], Any] = {}
    for n in summary["nodes"]:
        name = n["node"]
        n.pop("traceback", None)
        if name in memo["live"]:
            echo_live.update(_replay_live(memo, name, live_inputs[name], out, foreign, n))
        else:
            n.update(status="cached", seconds=0.0, items_ran=0)
        reports[name] = _report(
            name,
            n["type"],
            n["status"],
            seconds=n["seconds"],
            items=n.get("items", 0),
            items_failed=n.get("items_failed", 0),
            error=n.get("error"),
            hint=n.get("hint"),
            trace=n.get("traceback"),
            unexpected=bool(n.get("traceback")),
            messages=list(n.get("messages", [])),
        )
    result = Replayed(
        run_id, out, reports, _echo(memo["echo"], echo_live), memo["where"], memo["upstream"]
    )
    summary[run_folder.MARKER] = run_folder.marker(run_id)
    summary.update(run_id=run_id, out_dir=str(out), ok=result.ok, notes=[], failed_items=[])
    outputs.write_whole(out / "run.json", json.dumps(summary, indent=1).encode())
    result.notes.extend(hooks.announce("run_written", out))  # report.html, as a computed run gets
    return result


def _link_files(memo: dict[str, Any], mdir: Path, out: Path) -> bool:
    """The memo's run-folder files linked into ``out``, and their new stamps noted; False (and
    ``out`` as it was) when they cannot be (a full disk, say): a real run then reports it."""
    from stereograph.core import outputs

    made: list[Path] = []
    folders: set[str] = set()
    src_root, out_root = str(mdir / "files"), str(out)
    try:
        for rel in memo["files"]:
            src, dest = f"{src_root}/{rel}", f"{out_root}/{rel}"
            if os.path.dirname(dest) not in folders:
                os.makedirs(os.path.dirname(dest), exist_ok=True)
                folders.add(os.path.dirname(dest))
            try:
                os.link(src, dest)  # (a new name in an emptied folder: atomic as it is)
            except OSError:  # there already, or another disk: the careful way
                outputs.link_or_copy(Path(src), Path(dest))
            made.append(Path(dest))
    except OSError:
        for f in made:
            f.unlink(missing_ok=True)
        # the folders made for them
        for d, _dirs, _files in sorted(os.walk(out), key=lambda w: -len(w[0])):
            with contextlib.suppress(OSError):
                os.rmdir(d)
        return False
    stamps = {}
    # (the link moved the ctime: the content was checked before)
    for rel, rec in memo["files"].items():
        rec["stamp"] = _stamp(f"{src_root}/{rel}")
        stamps[rel] = [rec["stamp"], rec["verified_ns"]]
    with contextlib.suppress(OSError):  # the new stamps: only a fast path for the next replay
        outputs.write_whole(mdir / STAMPS, json.dumps(stamps).encode())
    return True


def _replay_live(
    memo: dict[str, Any],
    name: str,
    inputs: dict[str, Any],
    out: Path,
    foreign: Any,
    line: dict[str, Any],
) -> dict[tuple[str, str], Any]:
    """Run a node that must run, and update its ``run.json`` ``line``; returns its values."""
    from stereograph.core import run_folder

    rep, values = _run_live(
        name, memo["live"][name], inputs, out, Path(memo["pipeline_dir"]), memo["plugins"]
    )
    # (with what it wrote into its folder itself, a failure log: as a real run records it)
    files = rep.files + run_folder.node_files(out, name, set(rep.files), foreign)
    line.update(
        status=rep.status,
        seconds=round(rep.seconds, 4),
        items_ran=0,
        error=rep.error,
        hint=rep.hint,
        messages=rep.messages,
        files=files,
    )
    if rep.unexpected and rep.trace:
        line["traceback"] = rep.trace
    return {(name, o): v for o, v in values.items()}


def _restamp(memo: dict[str, Any], mdir: Path) -> None:
    """The run-folder files' stamps as the last replay left them (its links moved their ctimes):
    ``stamps.json``, a small file beside the memo, so that a replay does not rewrite the memo with
    the inputs it keeps for the nodes that must run (half a megabyte for pick.yaml's plans)."""
    with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
        for rel, (stamp, verified_ns) in json.loads((mdir / STAMPS).read_text()).items():
            if rel in memo["files"] and isinstance(verified_ns, int):
                memo["files"][rel].update(stamp=stamp, verified_ns=verified_ns)


def _run_live(
    name: str,
    spec: dict[str, Any],
    inputs: dict[str, Any],
    out: Path,
    pipeline_dir: Path,
    plugins: list[str],
) -> tuple[SimpleNamespace, dict[str, Any]]:
    """Run a node that must run, as the runner does (same ``execute``), and write its outputs."""
    from stereograph.core import outputs
    from stereograph.core.calls import Task, close_resources, execute

    resources: dict[str, Any] = {}
    try:
        # params as data: execute() validates them with the node's model, as for a worker process
        res = execute(
            Task(
                spec["type"],
                plugins,
                spec["params"],
                inputs,
                name,
                None,
                str(out),
                str(pipeline_dir),
                spec["input_types"],
                resources,
            )
        )
    finally:
        close_resources(resources)
    rep = _report(
        name,
        spec["type"],
        "ran" if res.ok else "failed",
        seconds=res.seconds,
        messages=list(res.messages),
    )
    if not res.ok:
        rep.error, rep.hint, rep.trace, rep.unexpected = (
            res.error,
            res.hint,
            res.trace,
            not res.user_error,
        )
        return rep, {}
    for o, v in (res.outputs or {}).items():
        try:
            files = outputs.write_value(out / name / o, v)
        # as write_run_outputs: an output that cannot be written fails the node
        except Exception as e:
            rep.messages.append(f"could not write output '{o}': {e}")
            if isinstance(e, OSError) and rep.error is None:
                rep.status, rep.error = "failed", f"could not write output '{o}': {e.strerror or e}"
            continue
        rep.files += [str(f.relative_to(out)) for f in files]
    return rep, dict(res.outputs or {})


def _echo(recorded: list[list[Any]], live: dict[tuple[str, str], Any]) -> list[list[Any]]:
    """The console's entries, with those of the nodes that ran filled in from their values."""
    from stereograph.app.console import echo_entry

    out = []
    for e in recorded:
        if e[0] == "live":
            shown = echo_entry(live.get((e[1], e[2])))
            if shown is not None:
                out.append([f"{e[1]}.{e[2]}", *shown])
        else:
            out.append(e)
    return out
