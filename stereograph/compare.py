"""``stereograph compare``: run every combination of a few settings and tabulate the accuracy.

Usage::

    stereograph compare pipelines/compare-compensation.yaml \\
        --vary compensate_fit.type=none,polynomial,disparity_curve,lookup [--vary segment.type=...]

or a ``variants:`` block in the pipeline file (same keys; ``--vary`` adds to / replaces it)::

    variants:
      fit.type: [none, polynomial, lookup]
      fit.cv_folds: [5]

A key is ``node.param`` (nested params with more dots), ``node.type`` (the node's type;
a value without a dot is taken in the node's current kind, so ``none`` means
``compensator.none`` for a compensator node; params then fall back to the new type's
defaults plus the pipeline's ``defaults:`` block for that type, where per-type settings
belong) or ``node.inputs.port``. The combinations are the Cartesian product of the keys.

Every variant runs through :func:`stereograph.runner.run_graph` on one shared artifact
cache, so what the variants have in common (calibration, rectification, segmentation ...)
is computed once, and a later compare with one more value computes only that variant's
nodes. The engine knows no concrete node here: the accuracy is read from the pipeline's
*final* ``Location`` outputs (those no later node turns into another Location), as
``measured - truth`` over the items of a split (``test`` by default); a fit time is
read from any saved result that reports ``fit_time_s``; the per-pair time is the sum, over
the nodes that run once per item, of their compute seconds per item (remembered in the
cache folder for nodes served from the cache).

Public API::

    from stereograph.compare import compare
    res = compare("pipelines/compare-compensation.yaml", ["fit.type=none,polynomial"], out_dir="out")
    res.rows            # one dict per (variant, final Location output): the table
    res.variants[1].ran # nodes that computed anything in that variant's run

The CLI hook is :func:`add_subcommand` (the ``stereograph`` parser calls it) and
:func:`main` runs parsed arguments.
"""

from __future__ import annotations

import copy
import csv
import itertools
import json
import math
import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stereograph.config import PipelineDoc, apply_override, load_pipeline
from stereograph.errors import ConfigError, UsageError
from stereograph.graph import Graph, build_graph

__all__ = [
    "CompareResult",
    "Variant",
    "VariantResult",
    "add_compare_subcommand",
    "add_subcommand",
    "compare",
    "expand_variants",
    "final_location_outputs",
    "location_errors",
    "main",
    "parse_vary",
]

AXES = ("x", "y", "z")
TIMINGS_FILE = "compare-timings.json"


# --------------------------------------------------------------------------- variants


@dataclass
class Variant:
    """One combination of settings."""

    index: int
    settings: dict[str, Any]  # "node.field" -> value (as given)
    overrides: list[str] = field(default_factory=list)  # what was applied to the document

    @property
    def label(self) -> str:
        return ", ".join(f"{k}={_show(v)}" for k, v in self.settings.items())

    @property
    def slug(self) -> str:
        text = "_".join(f"{k}-{_show(v)}" for k, v in self.settings.items())
        return f"v{self.index:02d}_" + re.sub(r"[^A-Za-z0-9._=-]+", "-", text)[:80]


def _show(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


def parse_vary(text: str) -> tuple[str, list[Any]]:
    """Split ``node.field=v1,v2,...`` into the key and the values (each parsed as YAML).

    Values are read as one YAML flow sequence, so ``fit.bin_edges_cm=[30, 40, 60],[30, 60]``
    gives two lists.
    """
    if "=" not in text:
        raise UsageError(f"--vary '{text}' is not of the form node.field=v1,v2,...",
                         hint="for example --vary fit.type=none,polynomial")
    key, rhs = (s.strip() for s in text.split("=", 1))
    parts = key.split(".")
    if len(parts) < 2 or not all(parts):
        raise UsageError(f"--vary '{text}': the left side must be node.field (node.type or node.param)",
                         hint="for example --vary fit.degree=1,2,3")
    from stereograph.config import parse_yaml

    try:  # the bounds of a pipeline file apply (an alias bomb, deep nesting)
        values = parse_yaml(f"[{rhs}]", f"--vary {key}", record_lines=False)[0]
    except ConfigError as e:
        if not getattr(e, "syntax", False):
            raise
        values = [v.strip() for v in rhs.split(",")]
    if not values or any(v is None for v in values):
        raise UsageError(f"--vary '{text}' lists no (or an empty) value", hint="give comma-separated values")
    return key, list(values)


def _override_text(doc: PipelineDoc, key: str, value: Any) -> str | None:
    """The ``--set`` text that applies one setting, or None when it changes nothing."""
    node, _, fieldname = key.partition(".")
    if node not in doc.nodes:
        return f"{key}={json.dumps(value)}"  # apply_override names the bad node
    if fieldname == "type":
        value = str(value)
        current = str(doc.nodes[node]["type"])
        if "." not in value:
            value = current.split(".", 1)[0] + "." + value
        if value == current:
            return None  # same type: keep the params written in the pipeline
    return f"{key}={json.dumps(value)}"


def expand_variants(doc: PipelineDoc, vary: Iterable[str] = ()) -> list[Variant]:
    """The Cartesian product of the pipeline's ``variants:`` block and ``--vary`` options."""
    space: dict[str, list[Any]] = {}
    for k, values in (doc.variants or {}).items():
        if "." not in str(k):
            raise ConfigError(f"variants key '{k}' must be node.field", doc.where("variants", k),
                              hint="for example 'fit.type: [none, polynomial]'")
        space[str(k)] = list(values)
    for text in vary:
        k, values = parse_vary(text)
        space[k] = values
    if not space:
        raise UsageError(f"nothing to compare in {doc.path.name}: no --vary and no 'variants:' block",
                         hint="add --vary node.field=v1,v2 (e.g. --vary fit.type=none,polynomial)")
    keys = list(space)
    return [Variant(i + 1, dict(zip(keys, combo))) for i, combo in enumerate(itertools.product(*space.values()))]


def variant_graph(doc: PipelineDoc, variant: Variant) -> Graph:
    """Apply a variant's settings to a copy of the document and validate it."""
    vdoc = copy.deepcopy(doc)
    vdoc.variants = {}
    variant.overrides = []
    # A type change resets the node's params, so types go first and params set with them survive.
    ordered = sorted(variant.settings.items(), key=lambda kv: kv[0].split(".", 1)[1] != "type")
    for key, value in ordered:
        text = _override_text(vdoc, key, value)
        if text is not None:
            apply_override(vdoc, text)
            variant.overrides.append(text)
    return build_graph(vdoc)


# --------------------------------------------------------------------------- metrics


def final_location_outputs(graph: Graph) -> list[tuple[str, str]]:
    """``(node, output)`` of type Location that no later node turns into another Location."""
    out = []
    for name in graph.order:
        for port, decl in graph.nodes[name].spec.outputs.items():
            if decl.type != "Location":
                continue
            later = graph.downstream(name)
            if not any(o.type == "Location" for n in later for o in graph.nodes[n].spec.outputs.values()):
                out.append((name, port))
    return out


def location_errors(locations: dict[str, Any], split: str = "test") -> dict[str, Any]:
    """Errors ``measured - truth`` (cm) of the found items of a split that carry truth.

    Parameters
    ----------
    locations : dict
        ``{item_id: Location}``.
    split : {"test", "train", "all"}
        Which items count. When no item carries a ``split`` key, every item counts
        (and ``split_used`` says "all").

    Returns
    -------
    dict
        ``{"errors": (N, 3) cm, "truth": (N, 3) cm, "n": items in the split, "n_found",
        "n_truth", "n_extrapolated", "split_used"}``.
    """
    items = [v for v in locations.values() if isinstance(v, dict)]
    have_split = any("split" in v for v in items)
    used = split if have_split else "all"
    chosen = [v for v in items if used == "all" or v.get("split") == used]
    errs, truth, n_found, n_extra = [], [], 0, 0
    for loc in chosen:
        if not loc.get("found"):
            continue
        n_found += 1
        t = loc.get("truth_cm")
        xyz = [loc.get("x_cm"), loc.get("y_cm"), loc.get("z_cm")]
        if t is None or any(c is None for c in xyz):
            continue
        e = np.subtract(np.asarray(xyz, float), np.asarray(t, float)[:3])
        if not np.all(np.isfinite(e)):
            continue
        errs.append(e)
        truth.append(np.asarray(t, float)[:3])
        n_extra += bool(loc.get("extrapolated"))
    return {
        "errors": np.array(errs, float).reshape(-1, 3),
        "truth": np.array(truth, float).reshape(-1, 3),
        "n": len(chosen),
        "n_found": n_found,
        "n_truth": len(errs),
        "n_extrapolated": n_extra,
        "split_used": used,
    }


def _axis_stats(e: np.ndarray) -> dict[str, dict[str, float | None]]:
    out = {}
    for k, axis in enumerate(AXES):
        col = e[:, k] if len(e) else np.zeros(0)
        out[axis] = {
            "mean_cm": float(np.mean(col)) if len(col) else None,
            "std_cm": float(np.std(col, ddof=1)) if len(col) > 1 else None,
            "rms_cm": float(np.sqrt(np.mean(col**2))) if len(col) else None,
            "max_abs_cm": float(np.max(np.abs(col))) if len(col) else None,
        }
    return out


def _find_fit_times(value: Any) -> list[float]:
    """Every ``fit_time_s`` number in a (saved) result, at any depth of dicts."""
    found = []
    if isinstance(value, dict):
        t = value.get("fit_time_s")
        if isinstance(t, (int, float)) and math.isfinite(t):
            found.append(float(t))
        for k, v in value.items():
            if k != "fit_time_s" and isinstance(v, dict):
                found += _find_fit_times(v)
    return found


# --------------------------------------------------------------------------- timing ledger


def _lineages(graph: Graph, code: dict[Any, str] | None = None) -> dict[str, str]:
    """A config-level fingerprint of each node and everything upstream of it.

    Two variants whose node has the same fingerprint share that node's artifacts; the
    fingerprints also key the remembered per-item timings. ``code`` memoises source hashes.
    """
    from stereograph.cache import code_hash, hash_json

    code = {} if code is None else code
    lin: dict[str, str] = {}
    for name in graph.order:
        inst = graph.nodes[name]
        if inst.spec.fn not in code:
            code[inst.spec.fn] = code_hash(inst.spec.fn)[0]
        lin[name] = hash_json({
            "type": inst.type, "version": inst.spec.version, "code": code[inst.spec.fn],
            "params": inst.params.model_dump(mode="json"),
            "inputs": {p: [lin[s], o] for p, (s, o) in sorted(inst.inputs.items())},
        })
    return lin


class _Timings:
    """Seconds per item of per-item nodes, remembered next to the cache (best effort)."""

    def __init__(self, root: Path | None):
        self.path = None if root is None else Path(root) / TIMINGS_FILE
        self.data: dict[str, float] = {}
        if self.path is not None and self.path.exists():
            try:
                self.data = {k: float(v) for k, v in json.loads(self.path.read_text()).items()}
            except (OSError, ValueError, AttributeError):
                self.data = {}

    def save(self) -> None:
        if self.path is None:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(".tmp")
            tmp.write_text(json.dumps(self.data, indent=0, sort_keys=True))
            tmp.replace(self.path)
        except OSError:
            pass


def _per_pair_seconds(graph: Graph, result: Any, timings: _Timings, lin: dict[str, str]) -> float | None:
    total, known = 0.0, True
    for name in graph.order:
        inst = graph.nodes[name]
        if not inst.mapped:
            continue
        rep = result.reports[name]
        if rep.items and rep.items_ran == rep.items and rep.status == "ran":
            timings.data[lin[name]] = rep.seconds / rep.items
        if lin[name] in timings.data:
            total += timings.data[lin[name]]
        else:
            known = False
    return total if known else None


# --------------------------------------------------------------------------- running


@dataclass
class VariantResult:
    """What one variant's run gave."""

    variant: Variant
    ok: bool
    error: str | None
    status: dict[str, str]
    ran: set[str]
    out_dir: Path | None
    seconds: float
    fit_time_s: float | None
    per_pair_s: float | None
    outputs: list[dict[str, Any]]  # per final Location output: metrics + arrays


@dataclass
class CompareResult:
    """All variants, the table rows, and the files written."""

    pipeline: str
    keys: list[str]
    split: str
    out_dir: Path
    variants: list[VariantResult]
    rows: list[dict[str, Any]]
    files: dict[str, Path]

    @property
    def ok(self) -> bool:
        return all(v.ok for v in self.variants)

    def row(self, **settings: Any) -> dict[str, Any]:
        """The first row whose settings include these (``row(**{"fit.type": "none"})``)."""
        for r in self.rows:
            if all(r["settings"].get(k) == v for k, v in settings.items()):
                return r
        raise KeyError(settings)


class _PlainProgress:
    """Progress lines for a non-terminal (one per variant)."""

    def __init__(self, stream=None):
        self.stream = stream

    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False

    def variant_started(self, i: int, n: int, label: str) -> None:
        if self.stream:
            print(f"[{i}/{n}] {label} ...", file=self.stream, flush=True)

    def variant_done(self, vr: VariantResult) -> None:
        if self.stream:
            ran = ", ".join(n for n in vr.status if n in vr.ran) or "nothing (all cached)"
            state = "ok" if vr.ok else f"FAILED: {vr.error}"
            print(f"      {state}; computed: {ran} ({vr.seconds:.1f} s)", file=self.stream, flush=True)

    def node_started(self, name: str, n_items: int) -> None:
        pass

    def advance(self, name: str) -> None:
        pass


class _RichProgress(_PlainProgress):
    """A bar over the variants and one for the node running now."""

    def __init__(self, console):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        super().__init__(None)
        self.console = console
        self.p = Progress(TextColumn("{task.description:<48}"), BarColumn(), MofNCompleteColumn(),
                          TimeElapsedColumn(), console=console, transient=True)
        self.overall = None
        self.current = None

    def __enter__(self):
        self.p.__enter__()
        return self

    def __exit__(self, *a):
        self.p.__exit__(*a)
        return False

    def variant_started(self, i: int, n: int, label: str) -> None:
        if self.overall is None:
            self.overall = self.p.add_task("variants", total=n)
        self.p.update(self.overall, description=f"variant {i}/{n}: {label}"[:48])

    def variant_done(self, vr: VariantResult) -> None:
        self.p.advance(self.overall)
        ran = ", ".join(n for n in vr.status if n in vr.ran) or "nothing (cached)"
        from rich.markup import escape  # labels and errors are user text: print them literally

        mark = "[green]ok[/]" if vr.ok else f"[red]failed[/]: {escape(str(vr.error))}"
        self.console.print(f"{escape(vr.variant.label)}: {mark}; computed {escape(ran)} ({vr.seconds:.1f} s)")

    def node_started(self, name: str, n_items: int) -> None:
        if self.current is not None:
            self.p.remove_task(self.current)
        self.current = self.p.add_task(f"  {name}", total=max(n_items, 1))

    def advance(self, name: str) -> None:
        if self.current is not None:
            self.p.advance(self.current)


def _default_out(doc: PipelineDoc) -> Path:
    from stereograph.project import runs_dir
    from stereograph.runner import new_run_id

    return runs_dir(doc.directory) / doc.name / f"compare-{new_run_id()}"


def compare(
    pipeline_path: str | Path,
    vary: list[str] | None = None,
    out_dir: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    cache_dir: str | Path | None = None,
    split: str = "test",
    executor: Any = None,
    progress: Any = None,
    skip_invalid: bool = False,
    plots: bool = True,
) -> CompareResult:
    """Run every variant of a pipeline on one shared cache and tabulate their accuracy.

    Parameters
    ----------
    pipeline_path : str or Path
        The pipeline YAML.
    vary : list of str
        ``node.field=v1,v2,...`` each (added to the file's ``variants:`` block).
    out_dir : str or Path, optional
        Where ``compare.csv``, ``compare.json``, the plots and each variant's run
        outputs (``variants/<slug>/``) go; default ``runs/<name>/compare-<run id>``.
    overrides : list of str, optional
        ``--set`` overrides applied to every variant.
    cache_dir : str or Path, optional
        The shared artifact cache (default: next to the pipeline).
    split : {"test", "train", "all"}
        Which items the accuracy is computed on.
    executor, progress : optional
        As for :func:`stereograph.runner.run_graph`; ``progress`` may also have
        ``variant_started(i, n, label)`` / ``variant_done(variant_result)``.
    skip_invalid : bool
        Leave out combinations whose config does not validate (a param the varied
        type does not take, say) instead of refusing the whole comparison.
    plots : bool
        Write the PNG plots.

    Returns
    -------
    CompareResult

    Raises
    ------
    ConfigError / UsageError
        A bad pipeline or ``--vary``; with ``skip_invalid`` only if no variant is valid.
    """
    from stereograph.runner import default_cache_dir, run_graph

    if split not in ("test", "train", "all"):
        raise UsageError(f"--split {split}: choose test, train or all")
    doc = load_pipeline(pipeline_path, overrides or [])
    variants = expand_variants(doc, vary or [])
    graphs: list[tuple[Variant, Graph]] = []
    skipped: list[tuple[Variant, str]] = []
    for v in variants:
        try:
            graphs.append((v, variant_graph(doc, v)))
        except ConfigError as e:
            if not skip_invalid:
                e.message = f"variant {v.label}: {e.message}"
                if not e.hint:
                    e.hint = "fix the value, or pass --skip-invalid to leave such combinations out"
                raise
            skipped.append((v, str(e)))
    if not graphs:
        raise ConfigError(f"no variant of {doc.path.name} is valid: {skipped[0][1]}")
    finals = final_location_outputs(graphs[0][1])
    if not finals:
        raise ConfigError(f"{doc.path.name} has no Location output to measure",
                          hint="compare needs a pipeline that locates objects (a node with a Location output)")
    out = Path(out_dir) if out_dir is not None else _default_out(doc)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir(doc)
    timings = _Timings(cache)
    prog = progress if progress is not None else _PlainProgress(None)
    results: list[VariantResult] = []
    code: dict[Any, str] = {}
    shared: set[str] | None = None  # fingerprints of the first variant's nodes
    for i, (v, graph) in enumerate(graphs, 1):
        if hasattr(prog, "variant_started"):
            prog.variant_started(i, len(graphs), v.label)
        lin = _lineages(graph, code)
        vr = _run_variant(v, graph, cache, out / "variants" / v.slug, split, executor, prog, timings, run_graph,
                          lin, shared)
        if shared is None:
            shared = set(lin.values())
        results.append(vr)
        if hasattr(prog, "variant_done"):
            prog.variant_done(vr)
    timings.save()
    rows = _rows(results)
    res = CompareResult(str(doc.path), list(variants[0].settings), split, out, results, rows, {})
    res.files = _write(res, skipped, plots)
    return res


def _run_variant(v: Variant, graph: Graph, cache: Path, out: Path, split: str, executor: Any, prog: Any,
                 timings: _Timings, run_graph: Any, lin: dict[str, str], shared: set[str] | None) -> VariantResult:
    import time

    t0 = time.perf_counter()
    # The first variant writes every saved output; the others only those of their own nodes
    # (what they share with the first is the same artifact, already written there).
    measured = final_location_outputs(graph)
    result = run_graph(graph, cache_dir=cache, out_dir=out, executor=executor, progress=prog,
                       write_outputs=shared is None, keep={node for node, _ in measured})
    if shared is not None:
        _write_own_outputs(graph, result, out, {n for n, h in lin.items() if h not in shared})
    failed = [r for r in result.reports.values() if r.status in ("failed", "partial", "skipped")]
    error = "; ".join(f"{r.name}: {r.error}" for r in failed if r.error)[:400] or None
    outputs = []
    for node, port in measured:
        values = result.outputs(node, port) or {}
        if not isinstance(values, dict):
            values = {"": values}
        m = location_errors(values, split)
        outputs.append({"node": node, "output": port, **m, "axes": _axis_stats(m["errors"])})
    fit_times: list[float] = []
    for name, inst in graph.nodes.items():
        for port, decl in inst.spec.outputs.items():
            if decl.save and not graph.is_collection(name, port):
                fit_times += _find_fit_times(result.outputs(name, port))
    return VariantResult(
        variant=v, ok=result.ok, error=error, status=result.status, ran=set(result.ran), out_dir=out,
        seconds=time.perf_counter() - t0, fit_time_s=sum(fit_times) if fit_times else None,
        per_pair_s=_per_pair_seconds(graph, result, timings, lin), outputs=outputs,
    )


def _write_own_outputs(graph: Graph, result: Any, out: Path, own: set[str]) -> None:
    """Saved / terminal outputs of the given nodes, and a small ``run.json``, into ``out``."""
    from stereograph import outputs as outputs_mod

    terminal = set(graph.terminal())
    files: dict[str, list[str]] = {}
    for name in graph.order:
        if name not in own or result.reports[name].status in ("failed", "skipped"):
            continue
        for port, decl in graph.nodes[name].spec.outputs.items():
            if not (decl.save or name in terminal):
                continue
            value = result.outputs(name, port)
            stem = out / name / port
            if graph.is_collection(name, port):
                written = outputs_mod.write_collection(stem, value or {})
            elif value is not None:
                written = outputs_mod.write_value(stem, value)
            else:
                continue
            files.setdefault(name, []).extend(str(f.relative_to(out)) for f in written)
    summary = {
        outputs_mod.MARKER: {"format": 1, "run_id": result.run_id},  # a later run may clear this folder
        "run_id": result.run_id, "pipeline": result.pipeline, "overrides": list(graph.doc.overrides),
        "ok": result.ok, "outputs_of": sorted(own),
        "nodes": [{"node": r.name, "type": r.type, "status": r.status, "seconds": round(r.seconds, 4),
                   "items": r.items, "items_ran": r.items_ran, "error": r.error, "files": files.get(r.name, [])}
                  for r in result.reports.values()],
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "run.json").write_text(json.dumps(summary, indent=1))


def _rows(results: list[VariantResult]) -> list[dict[str, Any]]:
    rows = []
    multi = max((len(r.outputs) for r in results), default=0) > 1
    for vr in results:
        for o in vr.outputs or [{}]:
            row: dict[str, Any] = {
                "variant": vr.variant.label + (f" [{o['node']}.{o['output']}]" if multi and o else ""),
                "settings": dict(vr.variant.settings),
                "ok": vr.ok,
                "error": vr.error,
                "output": f"{o['node']}.{o['output']}" if o else None,
                "n": o.get("n", 0),
                "n_found": o.get("n_found", 0),
                "n_truth": o.get("n_truth", 0),
                "n_extrapolated": o.get("n_extrapolated", 0),
                "split": o.get("split_used"),
                "fit_time_s": vr.fit_time_s,
                "per_pair_s": vr.per_pair_s,
                "ran": sorted(vr.ran),
            }
            for axis in AXES:
                for stat, val in (o.get("axes", {}).get(axis) or {}).items():
                    row[f"{axis}_{stat}"] = val
            rows.append(row)
    return rows


# --------------------------------------------------------------------------- outputs


def _write(res: CompareResult, skipped: list[tuple[Variant, str]], plots: bool) -> dict[str, Path]:
    files: dict[str, Path] = {}
    cols = ["variant", *res.keys, "ok", "output", "split", "n", "n_found", "n_truth", "n_extrapolated"]
    cols += [f"{a}_{s}" for a in AXES for s in ("mean_cm", "std_cm", "rms_cm", "max_abs_cm")]
    cols += ["fit_time_s", "per_pair_s", "error"]
    path = res.out_dir / "compare.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in res.rows:
            w.writerow([_csv(r["settings"][c]) if c in res.keys else _csv(r.get(c)) for c in cols])
    files["csv"] = path
    doc = {
        "pipeline": res.pipeline,
        "keys": res.keys,
        "split": res.split,
        "rows": [{k: v for k, v in r.items()} for r in res.rows],
        "variants": [
            {"label": vr.variant.label, "settings": vr.variant.settings, "overrides": vr.variant.overrides,
             "ok": vr.ok, "error": vr.error, "status": vr.status, "ran": sorted(vr.ran),
             "seconds": round(vr.seconds, 3), "fit_time_s": vr.fit_time_s, "per_pair_s": vr.per_pair_s,
             "out_dir": str(vr.out_dir)}
            for vr in res.variants
        ],
        "skipped_invalid": [{"label": v.label, "error": e} for v, e in skipped],
    }
    path = res.out_dir / "compare.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1, default=_json_default))
    tmp.replace(path)
    files["json"] = path
    if plots:
        files.update(_plots(res))
    return files


def _csv(v: Any) -> Any:
    if isinstance(v, float):
        return f"{v:.6g}"
    if v is None:
        return ""
    return v if isinstance(v, (str, int, bool)) else json.dumps(v)


def _json_default(v: Any) -> Any:
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, (set, tuple)):
        return sorted(v)
    return str(v)


def _varying_keys(res: CompareResult) -> list[str]:
    """The keys whose value differs between variants (all keys when none does)."""
    return [k for k in res.keys if len({_show(x.variant.settings[k]) for x in res.variants}) > 1] or res.keys


def _short_label(res: CompareResult, v: Variant) -> str:
    """Only the settings that differ between variants (plots have little room)."""
    return ", ".join(_show(v.settings[k]) for k in _varying_keys(res))


def _series(res: CompareResult) -> list[tuple[str, dict[str, Any]]]:
    multi = max((len(v.outputs) for v in res.variants), default=0) > 1
    out = []
    for vr in res.variants:
        for o in vr.outputs:
            if len(o["errors"]):
                out.append((_short_label(res, vr.variant) + (f" [{o['node']}]" if multi else ""), o))
    return out


def _plots(res: CompareResult) -> dict[str, Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = _series(res)
    files: dict[str, Path] = {}
    if not series:
        return files
    colours = plt.get_cmap("tab10")
    fig, ax = plt.subplots(figsize=(8, 5), dpi=110)
    for i, (label, o) in enumerate(series):
        z, ez = o["truth"][:, 2], o["errors"][:, 2]
        c = colours(i % 10)
        ax.scatter(z, ez, s=9, alpha=0.45, color=c)
        order = np.argsort(z)
        nb = max(1, min(8, len(z) // 6))
        bins = np.array_split(order, nb)
        ax.plot([z[b].mean() for b in bins], [ez[b].mean() for b in bins], "-o", ms=3, color=c, label=label)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("true distance z (cm)")
    ax.set_ylabel("z error, measured - true (cm)")
    ax.set_title(f"z error vs distance ({res.split} split; lines: binned means)\n"
                 + ", ".join(_varying_keys(res)), fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = res.out_dir / "z_error_vs_distance.png"
    fig.savefig(path)
    plt.close(fig)
    files["z_error_vs_distance"] = path

    labels = [s[0] for s in series]
    fig, axes = plt.subplots(1, 3, figsize=(min(24.0, 3 + 3 * 0.55 * len(series)), 4.5), dpi=110, squeeze=False)
    for k, axis in enumerate(AXES):
        a = axes[0, k]
        a.boxplot([o["errors"][:, k] for _, o in series], showfliers=True)
        a.set_xticks(range(1, len(labels) + 1), labels, rotation=35, ha="right", fontsize=7)
        a.axhline(0, color="k", lw=0.6)
        a.set_title(f"{axis} error, measured - true (cm)")
    fig.tight_layout()
    path = res.out_dir / "error_boxplots.png"
    fig.savefig(path)
    plt.close(fig)
    files["error_boxplots"] = path
    return files


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "–"
    return f"{v:.{digits}f}"


def _table_columns(narrow: bool) -> list[tuple[str, Any]]:
    """(header, cell function of a row) of the printed table; fewer columns on a narrow terminal."""
    def pct(r: dict, a: str, s: str) -> str:
        return _fmt(r.get(f"{a}_{s}_cm"))

    cols: list[tuple[str, Any]] = (
        [("found", lambda r: f"{r['n_found']}/{r['n']}")] if narrow
        else [("n", lambda r: str(r["n"])), ("found", lambda r: str(r["n_found"]))])
    stats = ("rms",) if narrow else ("mean", "std", "rms")
    for a in AXES:
        for st in (("mean", "std", "rms") if a == "z" else stats):
            cols.append((f"{a} {st.replace('rms', 'RMS')}", lambda r, a=a, st=st: pct(r, a, st)))
    if not narrow:
        cols.append(("extrap.", lambda r: str(r["n_extrapolated"])))
        cols.append(("fit s", lambda r: _fmt(r["fit_time_s"], 4)))
    cols.append(("pair ms", lambda r: _fmt(None if r["per_pair_s"] is None else 1000 * r["per_pair_s"], 1)))
    return cols


def print_table(res: CompareResult, console: Any = None) -> None:
    """The comparison as a rich table (cm), best z RMS in bold green.

    On a terminal narrower than 150 columns x and y show their RMS only and the fit time and
    extrapolation count are left out (compare.csv has everything).
    """
    from rich import box
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    con = console or Console(highlight=False)
    keys = _varying_keys(res)
    fixed = [f"{k}={_show(res.variants[0].variant.settings[k])}" for k in res.keys if k not in keys]
    narrow = con.width < 150
    t = Table(title=escape(f"compare {Path(res.pipeline).name} — {res.split} split, errors = measured − truth (cm)"
                           + (f"; fixed: {', '.join(fixed)}" if fixed else "")), title_justify="left",
              **({"box": box.SIMPLE_HEAD, "pad_edge": False} if narrow else {}))
    cols = _table_columns(narrow)
    for k in keys:
        width = max(len(_show(r["settings"][k])) for r in res.rows) if res.rows else 4
        t.add_column(escape(k), no_wrap=True, min_width=min(width, 22))
    for header, _ in cols:
        t.add_column(header, justify="right", no_wrap=True)
    zs = [r.get("z_rms_cm") for r in res.rows if r.get("z_rms_cm") is not None]
    best = min(zs) if zs else None
    for r in res.rows:
        cells = [escape(_show(r["settings"][k])) for k in keys]
        if not r["ok"] and not r.get("n_truth"):
            t.add_row(*cells, *(["–"] * len(cols)), style="red")
            continue
        style = "bold green" if best is not None and r.get("z_rms_cm") == best else ("red" if not r["ok"] else None)
        t.add_row(*cells, *(fn(r) for _, fn in cols), style=style)
    con.print(t)
    for vr in res.variants:
        if not vr.ok:
            con.print(f"[red]variant {escape(vr.variant.label)} failed:[/] {escape(str(vr.error))}")


# --------------------------------------------------------------------------- CLI


def add_subcommand(subparsers: Any) -> Any:
    """Add ``compare`` to the ``stereograph`` command's sub-parsers."""
    sp = subparsers.add_parser("compare", help="run every combination of --vary settings and compare accuracy")
    sp.add_argument("pipeline", help="pipeline YAML file")
    sp.add_argument("--vary", action="append", default=[], metavar="NODE.FIELD=V1,V2,...",
                    help="values to try for a param or a node's type (NODE.type=...); repeatable: every "
                         "combination runs. Adds to the file's 'variants:' block")
    sp.add_argument("--set", action="append", default=[], metavar="NODE.PARAM=VALUE",
                    help="override applied to every variant; repeatable")
    sp.add_argument("--out", help="output folder (default runs/<name>/compare-<run-id>)")
    sp.add_argument("--cache-dir", help="shared artifact cache (default: the project's, see docs/cache.md)")
    sp.add_argument("--split", choices=["test", "train", "all"], default="test",
                    help="items the errors are computed on (default test)")
    sp.add_argument("--workers", type=int, default=1, help="processes for per-item nodes (default 1)")
    sp.add_argument("--skip-invalid", action="store_true",
                    help="leave out combinations whose config does not validate instead of refusing")
    sp.add_argument("--no-plots", action="store_true", help="do not write the PNG plots")
    sp.add_argument("--json", action="store_true", help="print compare.json instead of the table")
    sp.add_argument("--debug", action="store_true", help="show tracebacks")
    sp.set_defaults(fn=main)
    return sp


add_compare_subcommand = add_subcommand


def main(args: Any) -> int:
    """Run ``stereograph compare`` from parsed arguments; 0 when every variant ran, 1 otherwise."""
    from rich.console import Console

    from stereograph.runner import workers_executor

    wide = None if sys.stdout.isatty() else 240  # a log or pipe: do not squeeze the table to 80 columns
    con = Console(highlight=False, soft_wrap=True, width=wide)
    err = Console(stderr=True, highlight=False, soft_wrap=True)
    executor = workers_executor(args.workers)
    kw = {"overrides": args.set, "cache_dir": args.cache_dir, "split": args.split, "executor": executor,
              "skip_invalid": args.skip_invalid, "plots": not args.no_plots}
    try:
        if sys.stdout.isatty() and not args.json:
            with _RichProgress(con) as prog:
                res = compare(args.pipeline, args.vary, args.out, progress=prog, **kw)
        else:
            res = compare(args.pipeline, args.vary, args.out, progress=_PlainProgress(sys.stderr), **kw)
    finally:
        executor.close()
    if args.json:
        print(res.files["json"].read_text())
    else:
        print_table(res, con)
        con.print(f"outputs: {res.out_dir} ({', '.join(p.name for p in res.files.values())})", markup=False)
    if not res.ok:
        err.print("[red]error:[/] some variants failed (see above); what finished is cached, so a rerun "
                  "computes only what is missing.")
        return 1
    return 0
