"""``stereograph compare``: run every combination of a few settings and tabulate the declared
metrics.

The variants come from ``--vary node.param=a,b`` or the pipeline's ``variants:`` block (their
Cartesian product); each runs through ``run_graph`` on one shared cache. Every ``Metrics`` output
becomes columns of ``compare.csv`` / ``compare.json`` and a panel of ``metrics.png``, plus the
engine's own per-pair time. This module knows nothing of what the numbers mean. Public:
:func:`compare` (``res.rows``, ``res.variants``), :func:`add_subcommand`, :func:`main`.
docs/engine.md ("stereograph compare") has the keys, the caching and the metric rules.
"""

from __future__ import annotations

import copy
import csv
import fnmatch
import io
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

from stereograph.app.ranking import PER_PAIR, best_row, is_best, show
from stereograph.core import hooks, registry
from stereograph.core.config import PipelineDoc, apply_override, check_node_named, load_pipeline
from stereograph.core.errors import ConfigError, UsageError, printable
from stereograph.core.graph import Graph, build_graph
from stereograph.core.outputs import check_folder_path, write_whole

__all__ = [
    "METRICS_TYPE",
    "CompareResult",
    "Variant",
    "VariantResult",
    "add_compare_subcommand",
    "add_subcommand",
    "collect_metrics",
    "compare",
    "expand_variants",
    "main",
    "metrics_outputs",
    "parse_vary",
    "print_table",
]

#: The artifact type of a node output that ``compare`` tabulates.
METRICS_TYPE = "Metrics"
TIMINGS_FILE = "compare-timings.json"
#: The one column the engine adds to the declared metrics (it measures it itself).


# --------------------------------------------------------------------------- variants


@dataclass
class Variant:
    """One combination of settings."""

    index: int
    settings: dict[str, Any]  # "node.field" -> value (as given)
    overrides: list[str] = field(default_factory=list)  # what was applied to the document
    # the keys whose value differs between variants (None: all)
    varying: tuple[str, ...] | None = None
    # key -> "--vary" or "variants:" (where it was given)
    sources: dict[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return ", ".join(f"{k}={show(v)}" for k, v in self.settings.items())

    @property
    def slug(self) -> str:
        # the folder name: the settings that tell the variants apart (a key with one value says
        # nothing)
        keys = [k for k in self.settings if self.varying is None or k in self.varying] or list(
            self.settings
        )
        text = "_".join(f"{k}-{show(self.settings[k])}" for k in keys)
        return f"v{self.index:02d}_" + re.sub(r"[^A-Za-z0-9._=-]+", "-", text)[:80]


def parse_vary(text: str) -> tuple[str, list[Any]]:
    """Split ``node.field=v1,v2,...`` into the key and the values (each parsed as YAML).

    Values are read as one YAML flow sequence, so ``fit.bin_edges_cm=[30, 40, 60],[30, 60]``
    gives two lists.
    """
    if "=" not in text:
        raise UsageError(
            f"--vary '{text}' is not of the form node.field=v1,v2,...",
            hint="for example --vary fit.type=none,polynomial",
        )
    key, rhs = (s.strip() for s in text.split("=", 1))
    parts = key.split(".")
    if len(parts) < 2 or not all(parts):
        raise UsageError(
            f"--vary '{text}': the left side must be node.field (node.type or node.param)",
            hint="for example --vary fit.degree=1,2,3",
        )
    from stereograph.core.config import parse_yaml

    try:  # the bounds of a pipeline file apply (an alias bomb, deep nesting)
        values = parse_yaml(f"[{rhs}]", f"--vary {key}", record_lines=False)[0]
    except ConfigError as e:
        if not getattr(e, "syntax", False):
            raise
        values = [v.strip() for v in rhs.split(",")]
    if not values or any(v is None for v in values):
        raise UsageError(
            f"--vary '{text}' lists no (or an empty) value", hint="give comma-separated values"
        )
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


# variants in one compare: each is a run (most of them cached, still a run folder each)
MAX_VARIANTS = 1000


def expand_variants(doc: PipelineDoc, vary: Iterable[str] = ()) -> list[Variant]:
    """The Cartesian product of the pipeline's ``variants:`` block and ``--vary`` options."""
    space: dict[str, list[Any]] = {}
    sources: dict[str, str] = {}
    for k, values in (doc.variants or {}).items():
        if "." not in str(k):
            raise ConfigError(
                f"variants key '{k}' must be node.field",
                doc.where("variants", k),
                hint="for example 'fit.type: [none, polynomial]'",
            )
        # (a key naming no node fails every combination: not one variant's problem for
        # --skip-invalid)
        check_node_named(
            doc, str(k).split(".", 1)[0], f"variants key '{k}'", doc.where("variants", k)
        )
        space[str(k)], sources[str(k)] = list(values), "variants:"
    given: dict[str, str] = {}
    for text in vary:
        k, values = parse_vary(text)
        check_node_named(doc, k.split(".", 1)[0], f"--vary '{text}'")
        if k in given:  # (the second list silently replaced the first)
            raise UsageError(
                f"--vary {k} is given twice ('{given[k]}' and '{text}')",
                hint=f"give every value in one list: --vary {k}=v1,v2,v3",
            )
        given[k] = text
        space[k], sources[k] = values, "--vary"
    if not space:
        raise UsageError(
            f"nothing to compare in {doc.path.name}: no --vary and no 'variants:' block",
            hint="add --vary node.field=v1,v2 (e.g. --vary fit.type=none,polynomial)",
        )
    keys = list(space)
    n = math.prod(len(v) for v in space.values())
    # (60,000 variants were built, then run, silently for minutes before the first line)
    if n > MAX_VARIANTS:
        sizes = " x ".join(f"{len(space[k])} {k}" for k in keys)
        raise UsageError(
            f"{n} variants ({sizes}): more than one compare runs ({MAX_VARIANTS})",
            hint="vary fewer settings or fewer values at once, and compare the best of each",
        )
    varying = tuple(k for k in keys if len(space[k]) > 1)
    return [
        Variant(i + 1, dict(zip(keys, combo)), varying=varying, sources=sources)
        for i, combo in enumerate(itertools.product(*space.values()))
    ]


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
            apply_override(vdoc, text, variant.sources.get(key, "--set"))
            variant.overrides.append(text)
    return build_graph(vdoc)


# --------------------------------------------------------------------------- metrics


def metrics_outputs(graph: Graph) -> list[tuple[str, str]]:
    """``(node, output)`` of every single (non-collection) output declared ``Out("Metrics")``, in
    run order."""
    return [
        (name, port)
        for name in graph.order
        for port, decl in graph.nodes[name].spec.outputs.items()
        if decl.type == METRICS_TYPE and not graph.is_collection(name, port)
    ]


def _number(value: Any) -> float | int | None:
    """A metric's value as a plain number (None for a missing or non-numeric one)."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, np.ndarray) and value.size == 1:
        return _number(value.item())
    return None


def collect_metrics(values: dict[tuple[str, str], Any]) -> dict[str, float | int | None]:
    """Merge the Metrics outputs of one run into one flat row, in declaration order.

    Parameters
    ----------
    values : dict
        ``{(node, output): {name: number, ...}}``; a value that is not a mapping is skipped.

    Returns
    -------
    dict
        ``{name: number}``; a name reported by more than one output is prefixed ``node.``
        (``node.output.`` when one node reports it twice).
    """
    owners: dict[str, list[tuple[str, str]]] = {}
    for key, m in values.items():
        for name in (m or {}) if isinstance(m, dict) else ():
            owners.setdefault(str(name), []).append(key)
    row: dict[str, float | int | None] = {}
    for (node, port), m in values.items():
        if not isinstance(m, dict):
            continue
        for name, value in m.items():
            who = owners[str(name)]
            if len(who) == 1:
                col = str(name)
            elif len({n for n, _ in who}) == len(who):
                col = f"{node}.{name}"
            else:
                col = f"{node}.{port}.{name}"
            row[col] = _number(value)
    return row


def _split_overrides(graph: Graph, split: str | None) -> list[str]:
    """``--split``: set the ``split`` param of every node that declares metrics and takes one."""
    if split is None:
        return []
    nodes = sorted({n for n, _ in metrics_outputs(graph)})
    return [
        f"{n}.split={json.dumps(split)}"
        for n in nodes
        if "split" in graph.nodes[n].spec.params.model_fields
    ]


# --------------------------------------------------------------------------- timing ledger


def _lineages(graph: Graph, code: dict[Any, str] | None = None) -> dict[str, str]:
    """A config-level fingerprint of each node and everything upstream of it.

    Two variants whose node has the same fingerprint share that node's artifacts; the
    fingerprints also key the remembered per-item timings. ``code`` memoises source hashes.
    """
    from stereograph.core.cache import code_hash
    from stereograph.core.digests import hash_json

    code = {} if code is None else code
    lin: dict[str, str] = {}
    for name in graph.order:
        inst = graph.nodes[name]
        if inst.spec.fn not in code:
            code[inst.spec.fn] = code_hash(inst.spec.fn)[0]
        lin[name] = hash_json(
            {
                "type": inst.type,
                "version": inst.spec.version,
                "code": code[inst.spec.fn],
                "params": inst.params.model_dump(mode="json"),
                "inputs": {p: [lin[s], o] for p, (s, o) in sorted(inst.inputs.items())},
            }
        )
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


def _per_pair_seconds(
    graph: Graph, result: Any, timings: _Timings, lin: dict[str, str]
) -> float | None:
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
    per_pair_s: float | None
    metrics: dict[str, float | int | None]  # the declared metrics, merged (see collect_metrics)


@dataclass
class CompareResult:
    """All variants, the table rows, and the files written."""

    pipeline: str
    keys: list[str]
    split: str | None
    out_dir: Path
    variants: list[VariantResult]
    rows: list[dict[str, Any]]
    files: dict[str, Path]
    # : ``(label, why)`` of each combination left out by ``skip_invalid`` (its config did not
    # validate)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    #: the metric the pipeline's ``compare: {metric: ...}`` names (``--best`` overrides it)
    ranked_by: str | None = None

    def shown_metrics(self, first: str | None = None) -> tuple[list[str], list[str]]:
        """``(shown, constant)``: the metric ``first`` names (``NAME[:how]``), then the metrics
        whose value differs between variants, in their order, the per-pair time last; and those the
        same in every one."""
        lead = (first or self.ranked_by or "").partition(":")[0]
        varies = [
            n
            for n in self.metric_names
            if n == PER_PAIR
            or len({_cell(n, r.get(n)) for r in self.rows}) > 1
            or len(self.rows) < 2
        ]
        shown = ([lead] if lead in self.metric_names else []) + [n for n in varies if n != lead]
        return shown, [n for n in self.metric_names if n not in shown]

    def same_in_every(self, names: list[str]) -> str:
        """``name value, ...`` of metrics every variant has the same value of (the first row's)."""
        return ", ".join(f"{n} {_cell(n, self.rows[0].get(n))}" for n in names)

    @property
    def ok(self) -> bool:
        return all(v.ok for v in self.variants)

    @property
    def metric_names(self) -> list[str]:
        """Every metric column, in the order the variants first report them (per-pair time last)."""
        names: dict[str, None] = {}
        for vr in self.variants:
            names.update(dict.fromkeys(vr.metrics))
        return [*names, PER_PAIR]

    def row(self, **settings: Any) -> dict[str, Any]:
        """The first row whose settings include these (``row(**{"fit.type": "none"})``)."""
        for r in self.rows:
            if all(r["settings"].get(k) == v for k, v in settings.items()):
                return r
        raise KeyError(settings)


class _PlainProgress:
    """Progress lines for a non-terminal: one per variant, and the run's per-node lines
    (:class:`stereograph.app.progress.PlainProgress`: a line per running node every few seconds)."""

    def __init__(self, stream=None, interval_s: float = 5.0):
        from stereograph.app.progress import PlainProgress

        self.stream = stream
        self.nodes = PlainProgress(stream, interval_s) if stream else None

    def __enter__(self):
        if self.nodes is not None:
            self.nodes.__enter__()
        return self

    def __exit__(self, *a):
        if self.nodes is not None:
            self.nodes.__exit__(*a)
        return False

    def variant_started(self, i: int, n: int, label: str) -> None:
        if self.stream:
            print(printable(f"[{i}/{n}] {label} ..."), file=self.stream, flush=True)

    def variant_skipped(self, label: str, why: str) -> None:
        if self.stream:
            print(
                printable(f"left out (its settings do not validate): {label}: {why}"),
                file=self.stream,
                flush=True,
            )

    def variant_done(self, vr: VariantResult) -> None:
        if self.stream:
            ran = _computed(vr)
            state = "ok" if vr.ok else f"FAILED: {vr.error}"
            print(
                printable(f"      {state}; computed: {ran} ({vr.seconds:.1f} s)"),
                file=self.stream,
                flush=True,
            )

    def node_started(self, name: str, n_items: int) -> None:
        if self.nodes is not None:
            self.nodes.node_started(name, n_items)

    def advance(self, name: str) -> None:
        if self.nodes is not None:
            self.nodes.advance(name)

    def item_failed(self, name: str) -> None:
        if self.nodes is not None:
            self.nodes.item_failed(name)

    def item_progress(self, name: str, done: float, total: float, unit: str = "items") -> None:
        if self.nodes is not None:
            self.nodes.item_progress(name, done, total, unit)


class _RichProgress(_PlainProgress):
    """A bar over the variants and one for the node running now."""

    def __init__(self, console):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        super().__init__(None)
        self.console = console
        self.p = Progress(
            TextColumn("{task.description:<48}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
            transient=True,
        )
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
        from rich.markup import escape

        self.p.update(self.overall, description=escape(printable(f"variant {i}/{n}: {label}"[:48])))

    def variant_done(self, vr: VariantResult) -> None:
        self.p.advance(self.overall)
        ran = _computed(vr)
        from rich.markup import escape  # labels and errors are user text: print them literally

        mark = "[green]ok[/]" if vr.ok else f"[red]failed[/]: {escape(str(vr.error))}"
        self.console.print(
            f"{escape(vr.variant.label)}: {mark}; computed {escape(ran)} ({vr.seconds:.1f} s)"
        )

    def node_started(self, name: str, n_items: int) -> None:
        if self.current is not None:
            self.p.remove_task(self.current)
        self.n_items, self.entries = max(n_items, 1), 0
        self.current = self.p.add_task(f"  {name}", total=self.n_items)

    def advance(self, name: str) -> None:
        if self.current is not None:
            self.entries += 1  # (back from the node's own count, if it showed one)
            self.p.update(self.current, total=self.n_items, completed=self.entries)

    def item_progress(self, name: str, done: float, total: float, unit: str = "items") -> None:
        if self.current is not None:  # the node's own count inside one call (a source's scenes)
            self.p.update(
                self.current, total=total, completed=done, description=f"  {name} ({unit})"
            )


def _default_out(doc: PipelineDoc) -> Path:
    from stereograph.core.project import runs_dir
    from stereograph.core.run_state import new_run_id

    return runs_dir(doc.directory) / doc.name / f"compare-{new_run_id()}"


# a compare.json key only stereograph writes: the folder holds its comparison
MARKER = "stereograph_compare"


def _compare_folder(out: Path) -> bool:
    """Whether ``out`` holds an earlier comparison: its ``compare.json`` (with :data:`MARKER`, or of
    the shape older versions wrote), or -- one that was interrupted before writing it -- only
    ``variants/`` of run folders that stereograph wrote."""
    from stereograph.core.outputs import MARKER as RUN_MARKER

    try:
        summary = json.loads((out / "compare.json").read_text())
        older = {"pipeline", "keys", "rows", "variants"}  # (before the marker)
        if isinstance(summary, dict) and (MARKER in summary or older <= set(summary)):
            return True
    except (OSError, ValueError):
        pass
    try:
        if {p.name for p in out.iterdir()} != {"variants"}:
            return False
        for v in (out / "variants").iterdir():
            run = json.loads((v / "run.json").read_text()) if any(v.iterdir()) else {RUN_MARKER: {}}
            if not (isinstance(run, dict) and isinstance(run.get(RUN_MARKER), dict)):
                return False
    except (OSError, ValueError):
        return False
    return True


def prepare_compare_dir(out: Path) -> None:
    """Make ``out`` ready for a comparison's files, or refuse it (:class:`ConfigError`): an existing
    file, a folder that cannot be made or written, a non-empty folder that is not an earlier
    comparison's (its files are never overwritten: ``compare.csv``, ``variants/``)."""
    check_folder_path(out)
    try:
        if out.is_dir() and any(out.iterdir()) and not _compare_folder(out):
            raise ConfigError(
                f"output folder {out} is not empty and is not the folder of an earlier stereograph "
                "comparison (no compare.json that stereograph wrote)",
                hint="choose another --out, or empty that folder",
            )
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(
            f"cannot use output folder {out}: {e.strerror or e}", hint="choose another --out"
        ) from None


def compare(
    pipeline_path: str | Path,
    vary: list[str] | None = None,
    out_dir: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    cache_dir: str | Path | None = None,
    split: str | None = None,
    executor: Any = None,
    progress: Any = None,
    skip_invalid: bool = False,
    plots: bool = True,
) -> CompareResult:
    """Run every variant of a pipeline on one shared cache and tabulate the metrics its nodes
    declare.

    Parameters
    ----------
    pipeline_path : str or Path
        The pipeline YAML.
    vary : list of str
        ``node.field=v1,v2,...`` each (added to the file's ``variants:`` block).
    out_dir : str or Path, optional
        Where ``compare.csv``, ``compare.json``, ``metrics.png`` and each variant's run
        outputs (``variants/<slug>/``) go; default ``runs/<name>/compare-<run id>``.
    overrides : list of str, optional
        ``--set`` overrides applied to every variant.
    cache_dir : str or Path, optional
        The shared artifact cache (default: next to the pipeline).
    split : str, optional
        Sets the ``split`` param of every node that declares metrics and takes one (a shortcut
        for ``--set node.split=...``); None leaves the pipeline's values.
    executor, progress : optional
        As for :func:`stereograph.core.runner.run_graph`; ``progress`` may also have
        ``variant_started(i, n, label)`` / ``variant_done(variant_result)``.
    skip_invalid : bool
        Leave out combinations whose config does not validate (a param the varied
        type does not take, say) instead of refusing the whole comparison.
    plots : bool
        Write ``metrics.png``.

    Returns
    -------
    CompareResult

    Raises
    ------
    ConfigError / UsageError
        A bad pipeline or ``--vary``, or a pipeline that declares no metrics; with
        ``skip_invalid`` only if no variant is valid.
    """
    from stereograph.core.run_state import default_cache_dir
    from stereograph.core.runner import run_graph

    overrides = list(overrides or [])
    doc = load_pipeline(pipeline_path, overrides)
    # The plugins are the pipeline's, not a variant's: a refusal or an import error is said once,
    # plainly (not as the first variant's problem, with --skip-invalid offered to leave out every
    # variant).
    registry.import_plugins(doc.plugins, doc.directory, doc.where("plugins"))
    if split is not None:
        extra = _split_overrides(build_graph(doc), split)
        if not extra:
            raise UsageError(
                f"--split {split}: no node of {doc.path.name} that declares metrics takes "
                "a 'split' "
                "param",
                hint="leave --split out, or set the split of the node you mean with --set",
            )
        doc = load_pipeline(pipeline_path, overrides + extra)
    variants = expand_variants(doc, vary or [])
    graphs: list[tuple[Variant, Graph]] = []
    skipped: list[tuple[Variant, str]] = []
    for v in variants:
        try:
            graphs.append((v, variant_graph(doc, v)))
        except ConfigError as e:
            if not skip_invalid:
                e.message = f"variant {v.label}: {e.message}"
                skip = "pass --skip-invalid to leave such combinations out"
                e.hint = (
                    f"{e.hint.rstrip('.')}; or {skip}" if e.hint else f"fix the value, or {skip}"
                )
                raise
            skipped.append((v, str(e)))
    if not graphs:
        raise ConfigError(f"no variant of {doc.path.name} is valid: {skipped[0][1]}")
    for v, why in skipped:
        if hasattr(progress, "variant_skipped"):
            progress.variant_skipped(v.label, why)
    if not metrics_outputs(graphs[0][1]):
        raise ConfigError(
            f"{doc.path.name} declares no metrics to compare",
            hint="add a node with an output of type Metrics (`stereograph nodes` shows each node's "
            "outputs), a report of the results, say",
        )
    out = Path(out_dir) if out_dir is not None else _default_out(doc)
    prepare_compare_dir(out)
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir(doc)
    timings = _Timings(cache)
    prog = progress if progress is not None else _PlainProgress(None)
    results: list[VariantResult] = []
    code: dict[Any, str] = {}
    shared: set[str] | None = None  # fingerprints of the first variant's nodes
    # The first variant alone (the others reuse what it caches), then, with --workers N or
    # --dask, the others N at a time: each sends its per-item work to the same pool, and their
    # own nodes (fits, reports) overlap. Their per-node progress is not shown (it would interleave).
    lanes = (
        max(1, int(getattr(executor, "workers", 1) or 1))
        if getattr(executor, "remote", False)
        else 1
    )
    for i, (v, graph) in enumerate(graphs[:1] if lanes > 1 else graphs, 1):
        if hasattr(prog, "variant_started"):
            prog.variant_started(i, len(graphs), v.label)
        lin = _lineages(graph, code)
        vr = _run_variant(
            v,
            graph,
            cache,
            out / "variants" / v.slug,
            executor,
            prog,
            timings,
            run_graph,
            lin,
            shared,
        )
        if shared is None:
            shared = set(lin.values())
        results.append(vr)
        if hasattr(prog, "variant_done"):
            prog.variant_done(vr)
    if lanes > 1 and len(graphs) > 1:
        import concurrent.futures as cf

        threads = cf.ThreadPoolExecutor(lanes)
        try:
            pending = []
            for i, (v, graph) in enumerate(graphs[1:], 2):
                if hasattr(prog, "variant_started"):
                    prog.variant_started(i, len(graphs), v.label)
                pending.append(
                    threads.submit(
                        _run_variant,
                        v,
                        graph,
                        cache,
                        out / "variants" / v.slug,
                        executor,
                        None,
                        timings,
                        run_graph,
                        _lineages(graph, code),
                        shared,
                    )
                )
            for fut in pending:
                vr = fut.result()
                results.append(vr)
                if hasattr(prog, "variant_done"):
                    prog.variant_done(vr)
        except BaseException:
            # Ctrl-C, SIGTERM: the variants not begun are dropped, not run one after another before
            # the interrupt gets through (the caller then ends the pool, and the running ones with
            # it)
            threads.shutdown(wait=False, cancel_futures=True)
            raise
        threads.shutdown()
    timings.save()
    res = CompareResult(
        str(doc.path),
        list(variants[0].settings),
        split,
        out,
        results,
        [],
        {},
        [(v.label, e) for v, e in skipped],
        doc.compare_metric,
    )
    res.rows = _rows(res)
    res.files = _write(res, skipped, plots)
    _write_page(res, overrides)
    return res


def _write_page(res: CompareResult, overrides: list[str] | None) -> None:
    """(Re)write ``compare.html`` with the files written so far (the CLI plots after
    ``compare``)."""
    try:
        from stereograph.app.compare_report import write_compare_html

        res.files["html"] = write_compare_html(res, list(overrides or []))
    except Exception as e:  # the table and CSV are written: a page problem must not hide them
        print(
            printable(f"note: compare.html not written: {type(e).__name__}: {e}"), file=sys.stderr
        )


def _failure_words(r: Any) -> str:
    """A failed node of a variant: its error (the first failing item's), how many items failed, its
    fix."""
    words = f"{r.name}: {r.error}"
    if r.items_failed > 1:
        words += f" ({r.items_failed} of {r.items} items failed; run.json lists each)"
    return words + (f" Fix: {r.hint}" if r.hint and r.hint not in words else "")


def _computed(vr: VariantResult) -> str:
    """What a variant computed, for its progress line: a node that failed was computed too (it is
    not 'all cached')."""
    parts = [n for n in vr.status if n in vr.ran] + [
        f"{n} (failed)" for n, st in vr.status.items() if st == "failed" and n not in vr.ran
    ]
    return ", ".join(parts) or ("nothing (all cached)" if vr.ok else "nothing")


def _run_variant(
    v: Variant,
    graph: Graph,
    cache: Path,
    out: Path,
    executor: Any,
    prog: Any,
    timings: _Timings,
    run_graph: Any,
    lin: dict[str, str],
    shared: set[str] | None,
) -> VariantResult:
    import time

    t0 = time.perf_counter()
    # The first variant writes every saved output; the others only those of their own nodes
    # (what they share with the first is the same artifact, already written there).
    measured = metrics_outputs(graph)
    result = run_graph(
        graph,
        cache_dir=cache,
        out_dir=out,
        executor=executor,
        progress=prog,
        write_outputs=shared is None,
        keep={node for node, _ in measured},
    )
    if shared is not None:
        _write_own_outputs(graph, result, out, {n for n, h in lin.items() if h not in shared})
    failed = [r for r in result.reports.values() if r.status in ("failed", "partial", "skipped")]
    error = "; ".join(_failure_words(r) for r in failed if r.error)[:700] or None
    metrics = collect_metrics({(node, port): result.outputs(node, port) for node, port in measured})
    return VariantResult(
        variant=v,
        ok=result.ok,
        error=error,
        status=result.status,
        ran=set(result.ran),
        out_dir=out,
        seconds=time.perf_counter() - t0,
        per_pair_s=_per_pair_seconds(graph, result, timings, lin),
        metrics=metrics,
    )


def _write_own_outputs(graph: Graph, result: Any, out: Path, own: set[str]) -> None:
    """Saved / terminal outputs of the given nodes, and a small ``run.json``, into ``out``."""
    from stereograph.core import outputs as outputs_mod

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
            # (a picture for people is JPEG here too, as in a run)
            if graph.is_collection(name, port):
                written = outputs_mod.write_collection(stem, value or {}, decl.lossy)
            elif value is not None:
                written = outputs_mod.write_value(stem, value, decl.lossy)
            else:
                continue
            files.setdefault(name, []).extend(str(f.relative_to(out)) for f in written)
    # what a node wrote into its folder itself (a failure log), as a run records it
    outputs_mod.add_node_files(out, graph.order, files, getattr(result.state, "foreign", {}))
    summary = {
        # a later run may clear this folder
        outputs_mod.MARKER: {"format": 1, "run_id": result.run_id},
        "run_id": result.run_id,
        "pipeline": result.pipeline,
        "overrides": list(graph.doc.overrides),
        "ok": result.ok,
        "outputs_of": sorted(own),
        "nodes": [
            {
                "node": r.name,
                "type": r.type,
                "status": r.status,
                "seconds": round(r.seconds, 4),
                "items": r.items,
                "items_ran": r.items_ran,
                "error": r.error,
                "files": files.get(r.name, []),
            }
            for r in result.reports.values()
        ],
    }
    out.mkdir(parents=True, exist_ok=True)
    write_whole(out / "run.json", json.dumps(summary, indent=1).encode())
    hooks.announce("run_written", out)  # its report.html (a page that fails is no failed compare)


def _rows(res: CompareResult) -> list[dict[str, Any]]:
    """One row per variant: its settings, every metric column (None where it reported none), run
    facts."""
    names = res.metric_names
    rows = []
    for vr in res.variants:
        row: dict[str, Any] = {
            "variant": vr.variant.label,
            "settings": dict(vr.variant.settings),
            "ok": vr.ok,
            "error": vr.error,
            "ran": sorted(vr.ran),
        }
        for name in names:
            row[name] = vr.per_pair_s if name == PER_PAIR else vr.metrics.get(name)
        rows.append(row)
    return rows


# --------------------------------------------------------------------------- outputs


def _write(res: CompareResult, skipped: list[tuple[Variant, str]], plots: bool) -> dict[str, Path]:
    files: dict[str, Path] = {}
    cols = ["variant", *res.keys, "ok", *res.metric_names, "error"]
    path = res.out_dir / "compare.csv"
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(cols)
    for r in res.rows:
        w.writerow([_csv(r["settings"][c]) if c in res.keys else _csv(r.get(c)) for c in cols])
    write_whole(path, text.getvalue().encode())  # whole or absent (an interrupt, a full disk)
    files["csv"] = path
    doc = {
        MARKER: {"format": 1},
        "pipeline": res.pipeline,
        "keys": res.keys,
        "split": res.split,
        "metrics": res.metric_names,
        "rows": [{k: v for k, v in r.items()} for r in res.rows],
        "variants": [
            {
                "label": vr.variant.label,
                "settings": vr.variant.settings,
                "overrides": vr.variant.overrides,
                "ok": vr.ok,
                "error": vr.error,
                "status": vr.status,
                "ran": sorted(vr.ran),
                "seconds": round(vr.seconds, 3),
                "per_pair_s": vr.per_pair_s,
                "metrics": vr.metrics,
                "out_dir": str(vr.out_dir),
            }
            for vr in res.variants
        ],
        "skipped_invalid": [{"label": v.label, "error": e} for v, e in skipped],
    }
    path = res.out_dir / "compare.json"
    write_whole(path, json.dumps(doc, indent=1, default=_json_default).encode())
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
    return [
        k for k in res.keys if len({show(x.variant.settings[k]) for x in res.variants}) > 1
    ] or res.keys


def _short_label(res: CompareResult, v: Variant) -> str:
    """Only the settings that differ between variants (plots have little room)."""
    return ", ".join(show(v.settings[k]) for k in _varying_keys(res))


def _plotted(res: CompareResult, names: list[str]) -> list[str]:
    """The chosen metrics with a number in at least one variant."""
    return [n for n in names if any(isinstance(r.get(n), (int, float)) for r in res.rows)]


def _plots(res: CompareResult, patterns: list[str] | None = None) -> dict[str, Path]:
    """``metrics.png``: one bar panel per metric (the chosen ones; by default those that differ
    between variants, the ranked one first), one bar per variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown, constant = res.shown_metrics()
    names = _plotted(
        res,
        select_metrics(shown + constant, patterns)
        if patterns
        else [n for n in shown if n != PER_PAIR],
    )
    if not names:
        return {}
    labels = [_short_label(res, vr.variant) for vr in res.variants]
    ncols = min(4, len(names))
    nrows = math.ceil(len(names) / ncols)
    height = max(2.2, 0.28 * len(labels) + 1.0)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(4.2 * ncols + 1.5, height * nrows), dpi=100, squeeze=False
    )
    ypos = np.arange(len(labels))
    for k, name in enumerate(names):
        a = axes[k // ncols, k % ncols]
        vals = [r.get(name) for r in res.rows]
        a.barh(ypos, [v if isinstance(v, (int, float)) else 0.0 for v in vals], color="tab:blue")
        for y, v in zip(ypos, vals):
            if not isinstance(v, (int, float)):
                a.text(0, y, " –", va="center", fontsize=7)
        a.axvline(0, color="k", lw=0.6)
        a.set_yticks(ypos, labels if k % ncols == 0 else [""] * len(labels), fontsize=7)
        a.invert_yaxis()
        a.set_title(name, fontsize=9)
        a.tick_params(axis="x", labelsize=7)
    for k in range(len(names), nrows * ncols):
        axes[k // ncols, k % ncols].axis("off")
    fig.suptitle(f"compare {Path(res.pipeline).name}: " + ", ".join(_varying_keys(res)), fontsize=9)
    fig.tight_layout()
    path = res.out_dir / "metrics.png"
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    write_whole(path, buf.getvalue())
    return {"metrics": path}


def select_metrics(names: list[str], patterns: list[str] | None) -> list[str]:
    """The names matching any of the shell-style patterns (``z_*``, ``*rms*``), in ``names``'s
    order; all for None."""
    if not patterns:
        return list(names)
    return [n for n in names if any(fnmatch.fnmatchcase(n, p) for p in patterns)]


def _fmt(v: Any, name: str = "") -> str:
    """A metric cell: integers as they are, seconds (a name ending ``_s``) with 4 decimals, other
    numbers with 3."""
    if v is None:
        return "–"
    if isinstance(v, int):
        return str(v)
    return f"{v:.4f}" if name.endswith("_s") else f"{v:.3f}"


def _header(name: str) -> str:
    return "pair ms" if name == PER_PAIR else name


def _cell(name: str, v: Any) -> str:
    # The engine's own per-pair time is shown in ms (as before), the declared metrics as they come.
    if name == PER_PAIR:
        return "–" if v is None else f"{1000 * v:.1f}"
    return _fmt(v, name)


#: ``--best NAME:HOW``: the row's value that ranks it (lowest ranked value is best).
def _chunks(
    res: CompareResult, keys: list[str], names: list[str], width: int, narrow: bool
) -> list[list[str]]:
    """The metric columns split into tables that each fit ``width`` (the setting columns repeat in
    each)."""
    pad = 2 if narrow else 3  # a column's padding and rule

    def col_width(header: str, cells: list[str]) -> int:
        return max([len(header), *map(len, cells)]) + pad

    used = sum(col_width(k, [show(r["settings"][k]) for r in res.rows]) for k in keys) + 1
    chunks: list[list[str]] = [[]]
    room = width - used
    for name in names:
        w = col_width(_header(name), [_cell(name, r.get(name)) for r in res.rows])
        if chunks[-1] and w > room:
            chunks.append([])
            room = width - used
        chunks[-1].append(name)
        room -= w
    return chunks


def print_table(
    res: CompareResult,
    console: Any = None,
    metrics: list[str] | None = None,
    best: str | None = None,
) -> None:
    """The comparison as rich tables: one row per variant, one column per metric.

    When the metrics do not fit the console's width they continue in a second table (and a
    third ...), each repeating the varied settings.

    Parameters
    ----------
    res : CompareResult
    console : rich Console, optional
    metrics : list of str, optional
        Shell-style patterns of the metric columns to show (default: all; compare.csv has all).
    best : str, optional
        ``NAME`` (lowest is best), ``NAME:max`` (highest) or ``NAME:abs`` (closest to zero): that
        row in bold green, among the variants that ran to the end (a failed one is marked FAILED,
        never best).
    """
    from rich import box
    from rich.markup import escape
    from rich.table import Table

    from stereograph.core.errors import console as safe_console

    con = console or safe_console(highlight=False)
    keys = _varying_keys(res)
    fixed = [f"{k}={show(res.variants[0].variant.settings[k])}" for k in res.keys if k not in keys]
    # A mistake in --metrics / --best is known only now that the variants ran: the table is printed
    # anyway (every metric, nothing marked), then the mistake is reported.
    mistakes: list[UsageError] = []
    shown, constant = res.shown_metrics(best)
    names = select_metrics(shown + constant, metrics) if metrics else shown
    if not names:
        mistakes.append(
            UsageError(
                "--metrics matches no metric", hint="choose among " + ", ".join(res.metric_names)
            )
        )
        names = shown
    try:
        top = best_row(res, best)
    except UsageError as e:
        mistakes.append(e)
        top = None
    narrow = con.width < 150
    chunks = _chunks(res, keys, names, con.width, narrow)
    failed = any(not r["ok"] for r in res.rows)
    for i, chunk in enumerate(chunks):
        title = (
            f"compare {Path(res.pipeline).name}"
            + (f" — split {res.split}" if res.split else "")
            + (f"; fixed: {', '.join(fixed)}" if fixed else "")
            + (f" ({i + 1}/{len(chunks)})" if len(chunks) > 1 else "")
        )
        t = Table(
            title=escape(title),
            title_justify="left",
            **({"box": box.SIMPLE_HEAD, "pad_edge": False} if narrow else {}),
        )
        for k in keys:
            t.add_column(escape(k), no_wrap=True)
        for name in chunk:
            t.add_column(_header(name), justify="right", no_wrap=True)
        if top is not None or failed:  # (the colour alone is lost in a log or a pipe)
            t.add_column("", no_wrap=True)
        for r in res.rows:
            cells = [escape(show(r["settings"][k])) for k in keys]
            marked = is_best(top, r)
            mark = (
                [f"<- best {top[0]}" if marked else "" if r["ok"] else "FAILED (see below)"]
                if top is not None or failed
                else []
            )
            if not r["ok"] and not any(
                isinstance(r.get(n), (int, float)) for n in names if n != PER_PAIR
            ):
                t.add_row(*cells, *(["–"] * len(chunk)), *mark, style="red")
                continue
            style = "bold green" if marked else ("red" if not r["ok"] else None)
            t.add_row(*cells, *(_cell(n, r.get(n)) for n in chunk), *mark, style=style)
        con.print(t)
    same = [n for n in constant if n not in names]
    # (not columns: a number that does not change tells nothing apart; compare.csv has them all)
    if same:
        con.print("the same in every variant: " + res.same_in_every(same), markup=False)
    for vr in res.variants:
        if not vr.ok:
            con.print(f"[red]variant {escape(vr.variant.label)} failed:[/] {escape(str(vr.error))}")
    for label, why in res.skipped:
        con.print(f"left out (--skip-invalid): {label}: {why}", markup=False)
    if (
        top is not None
        and top[1] == "min"
        and any(isinstance(r.get(top[0]), (int, float)) and r[top[0]] < 0 for r in res.rows)
    ):
        # a signed metric (a mean error, say): its lowest value is the farthest below zero
        con.print(
            f"note: {top[0]} has negative values, and --best {top[0]} marks the lowest "
            "(the most negative); "
            f"--best {top[0]}:abs marks the one closest to zero",
            markup=False,
        )
    if mistakes:
        raise mistakes[0]


# --------------------------------------------------------------------------- CLI


def add_subcommand(subparsers: Any) -> Any:
    """Add ``compare`` to the ``stereograph`` command's sub-parsers."""
    from stereograph.app.console import positive_int  # (run's own check of --workers)

    sp = subparsers.add_parser(
        "compare",
        help="run every combination of --vary settings and tabulate the metrics "
        "the pipeline's nodes declare",
    )
    sp.add_argument("pipeline", help="pipeline YAML file")
    sp.add_argument(
        "--vary",
        action="append",
        default=[],
        metavar="NODE.FIELD=V1,V2,...",
        help="values to try for a param or a node's type (NODE.type=...); repeatable: every "
        "combination runs. Adds to the file's 'variants:' block",
    )
    sp.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NODE.PARAM=VALUE",
        help="override applied to every variant; repeatable",
    )
    sp.add_argument("--out", help="output folder (default runs/<name>/compare-<run-id>)")
    sp.add_argument(
        "--cache-dir", help="shared artifact cache (default: the project's, see docs/cache.md)"
    )
    sp.add_argument(
        "--split",
        default=None,
        metavar="NAME",
        help="set the 'split' param of every node that declares metrics and takes one "
        "(test, train, all); default: as the pipeline says",
    )
    sp.add_argument(
        "--metrics",
        action="append",
        default=[],
        metavar="PATTERN",
        help="metric columns to print and plot, shell-style, comma-separated (z_*,'*rms*'); "
        "repeatable; "
        "default all (compare.csv always has all)",
    )
    sp.add_argument(
        "--best",
        metavar="METRIC[:max|:abs]",
        help="show the row with the lowest (:max the highest, :abs the closest to zero) METRIC in "
        "bold green, among the variants that ran to the end",
    )
    sp.add_argument(
        "--workers", type=positive_int, default=1, help="processes for per-item nodes (default 1)"
    )
    sp.add_argument(
        "--dask",
        metavar="ADDRESS",
        help="run every variant's per-item work on a Dask cluster "
        "('local' starts one with --workers processes; the cache and run folder must be on "
        "storage every worker sees: docs/parallel.md)",
    )
    sp.add_argument(
        "--skip-invalid",
        action="store_true",
        help="leave out combinations whose config does not validate instead of refusing",
    )
    sp.add_argument("--no-plots", action="store_true", help="do not write metrics.png")
    sp.add_argument("--json", action="store_true", help="print compare.json instead of the table")
    sp.add_argument("--debug", action="store_true", help="show tracebacks")
    sp.set_defaults(fn=main)
    return sp


add_compare_subcommand = add_subcommand


def main(args: Any) -> int:
    """Run ``stereograph compare`` from parsed arguments; 0 when every variant ran, 1 otherwise."""
    from stereograph.core.errors import console
    from stereograph.core.executors import workers_executor

    # a log or pipe: do not squeeze the table to 80 columns
    wide = None if sys.stdout.isatty() else 240
    # (user text printed with control characters escaped)
    con = console(highlight=False, soft_wrap=True, width=wide)
    err = console(stderr=True, highlight=False, soft_wrap=True)
    executor = workers_executor(args.workers, getattr(args, "dask", None))
    kw = {
        "overrides": args.set,
        "cache_dir": args.cache_dir,
        "split": args.split,
        "executor": executor,
        "skip_invalid": args.skip_invalid,
        "plots": False,
    }
    try:
        if sys.stdout.isatty() and not args.json:
            with _RichProgress(con) as prog:
                res = compare(args.pipeline, args.vary, args.out, progress=prog, **kw)
        else:
            with _PlainProgress(sys.stderr) as prog:
                res = compare(args.pipeline, args.vary, args.out, progress=prog, **kw)
    # (Ctrl-C: the pool's workers are ended, not waited for through the queue)
    except BaseException:
        executor.close(now=True)
        raise
    executor.close()
    patterns = [
        p.strip()
        for text in (getattr(args, "metrics", None) or [])
        for p in text.split(",")
        if p.strip()
    ]
    patterns = patterns or None
    if not args.no_plots:
        res.files.update(_plots(res, patterns))
        _write_page(res, args.set)  # the page was written before the plot: show it
    if args.json:
        print(res.files["json"].read_text())
    else:
        print_table(res, con, metrics=patterns, best=getattr(args, "best", None) or res.ranked_by)
        con.print(
            f"outputs: {res.out_dir} ({', '.join(p.name for p in res.files.values())})",
            markup=False,
        )
    if not res.ok:
        err.print(
            "[red]error:[/] some variants failed (see above); what finished is cached, so a rerun "
            "computes only what is missing."
        )
        return 1
    return 0
