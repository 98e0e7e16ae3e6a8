"""``stereograph compare``: run every combination of a few settings and tabulate the declared
metrics.

The variants (:mod:`stereograph.app.variants`) each run through ``run_graph`` on one shared cache.
Every ``Metrics`` output becomes columns of the table (:mod:`stereograph.app.compare_table`) and of
the files (:mod:`stereograph.app.compare_files`), plus the engine's own per-pair time. This module
knows nothing of what the numbers mean. Public: :func:`compare`, :func:`collect_metrics`,
:func:`metrics_outputs`, :func:`add_subcommand`, :func:`main`. docs/engine.md ("stereograph
compare") has the keys, the caching and the metric rules.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from stereograph.app.compare_files import (
    prepare_compare_dir,
    write_plots,
    write_tables,
    write_variant_outputs,
)
from stereograph.app.compare_progress import CompareBars, CompareLines
from stereograph.app.compare_result import CompareResult, VariantResult
from stereograph.app.compare_table import print_table
from stereograph.app.ranking import PER_PAIR
from stereograph.app.variants import Variant, expand_variants, variant_graph
from stereograph.core import registry
from stereograph.core.config import PipelineDoc, load_pipeline
from stereograph.core.errors import ConfigError, UsageError, printable
from stereograph.core.graph import Graph, build_graph
from stereograph.core.outputs import write_whole

#: The artifact type of a node output that ``compare`` tabulates.
METRICS_TYPE = "Metrics"
TIMINGS_FILE = "compare-timings.json"  # per-item seconds remembered beside the cache


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


def _lineages(graph: Graph, code: dict[Any, str] | None = None) -> dict[str, str]:
    """A config-level fingerprint of each node and everything upstream of it.

    Two variants whose node has the same fingerprint share that node's artifacts; the
    fingerprints also key the remembered per-item timings. ``code`` memoises source hashes.
    """
    from stereograph.core.code_keys import code_hash
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
        with contextlib.suppress(OSError):
            write_whole(self.path, json.dumps(self.data, indent=0, sort_keys=True).encode())


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


def _default_out(doc: PipelineDoc) -> Path:
    from stereograph.core.project import new_run_id, runs_dir

    return runs_dir(doc.directory) / doc.name / f"compare-{new_run_id()}"


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
    from stereograph.core.project import cache_dir as project_cache_dir

    overrides = list(overrides or [])
    doc = _load(pipeline_path, overrides, split)
    variants = expand_variants(doc, vary or [])
    graphs, skipped = _valid_graphs(doc, variants, skip_invalid)
    for v, why in skipped:
        _tell(progress, "variant_skipped", v.label, why)
    if not metrics_outputs(graphs[0][1]):
        raise ConfigError(
            f"{doc.path.name} declares no metrics to compare",
            hint="add a node with an output of type Metrics (`stereograph nodes` shows each node's "
            "outputs), a report of the results, say",
        )
    out = Path(out_dir) if out_dir is not None else _default_out(doc)
    prepare_compare_dir(out)
    cache = Path(cache_dir) if cache_dir is not None else project_cache_dir(doc.directory)
    timings = _Timings(cache)
    prog = progress if progress is not None else CompareLines(None)
    results = _run_variants(graphs, cache, out, executor, prog, timings)
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
    res.files = write_tables(res, skipped, plots)
    _write_page(res, overrides)
    return res


def _tell(progress: Any, event: str, *args: Any) -> None:
    """Pass a comparison's own event on to a progress display that takes it."""
    if hasattr(progress, event):
        getattr(progress, event)(*args)


def _load(pipeline_path: str | Path, overrides: list[str], split: str | None) -> PipelineDoc:
    """The pipeline with its overrides (and ``--split``'s), its plugins imported."""
    doc = load_pipeline(pipeline_path, overrides)
    # The plugins are the pipeline's, not a variant's: a refusal or an import error is said once,
    # plainly (not as the first variant's problem, with --skip-invalid offered to leave out every
    # variant).
    registry.import_plugins(doc.plugins, doc.directory, doc.where("plugins"))
    if split is None:
        return doc
    extra = _split_overrides(build_graph(doc), split)
    if not extra:
        raise UsageError(
            f"--split {split}: no node of {doc.path.name} that declares metrics takes a 'split' "
            "param",
            hint="leave --split out, or set the split of the node you mean with --set",
        )
    return load_pipeline(pipeline_path, overrides + extra)


def _valid_graphs(
    doc: PipelineDoc, variants: list[Variant], skip_invalid: bool
) -> tuple[list[tuple[Variant, Graph]], list[tuple[Variant, str]]]:
    """Each variant's graph; with ``skip_invalid``, ``(variant, why)`` of those that do not
    validate, else the first one's error."""
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
    return graphs, skipped


def _run_variants(
    graphs: list[tuple[Variant, Graph]],
    cache: Path,
    out: Path,
    executor: Any,
    prog: Any,
    timings: _Timings,
) -> list[VariantResult]:
    """Run the variants: the first alone (the others reuse what it caches), then, with --workers N
    or --dask, the others N at a time: each sends its per-item work to the same pool, and their own
    nodes (fits, reports) overlap. Their per-node progress is not shown (it would interleave)."""
    from stereograph.core.runner import run_graph

    code: dict[Any, str] = {}  # (source digests, shared by the variants' lineages)
    lanes = max(1, executor.workers) if executor is not None and executor.remote else 1

    def run(v: Variant, graph: Graph, lin: dict, progress: Any, shared: set | None):
        folder = out / "variants" / v.slug
        return _run_variant(
            v, graph, cache, folder, executor, progress, timings, run_graph, lin, shared
        )

    results: list[VariantResult] = []
    shared: set[str] | None = None  # fingerprints of the first variant's nodes
    for i, (v, graph) in enumerate(graphs[:1] if lanes > 1 else graphs, 1):
        _tell(prog, "variant_started", i, len(graphs), v.label)
        lin = _lineages(graph, code)
        results.append(run(v, graph, lin, prog, shared))
        _tell(prog, "variant_done", results[-1])
        shared = set(lin.values()) if shared is None else shared
    if lanes == 1 or len(graphs) == 1:
        return results
    threads = cf.ThreadPoolExecutor(lanes)
    try:
        pending = []
        for i, (v, graph) in enumerate(graphs[1:], 2):
            _tell(prog, "variant_started", i, len(graphs), v.label)
            pending.append(threads.submit(run, v, graph, _lineages(graph, code), None, shared))
        for fut in pending:
            results.append(fut.result())
            _tell(prog, "variant_done", results[-1])
    except BaseException:
        # Ctrl-C, SIGTERM: the variants not begun are dropped, not run one after another before
        # the interrupt gets through (the caller then ends the pool, and the running ones with it)
        threads.shutdown(wait=False, cancel_futures=True)
        raise
    threads.shutdown()
    return results


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
        write_variant_outputs(graph, result, {n for n, h in lin.items() if h not in shared})
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


def add_subcommand(subparsers: Any) -> Any:
    """Add ``compare`` to the ``stereograph`` command's sub-parsers."""
    from stereograph.app.console import add_executor_arguments  # (run's own --workers)

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
    sp.add_argument(
        "--split",
        default=None,
        metavar="NAME",
        help="set the 'split' param of every node that declares metrics and takes one "
        "(test, train, all); default: as the pipeline says",
    )
    add_executor_arguments(sp, "every variant's per-item nodes")
    sp.add_argument(
        "--skip-invalid",
        action="store_true",
        help="leave out combinations whose config does not validate instead of refusing",
    )
    sp.add_argument("--debug", action="store_true", help="show tracebacks")
    _add_output_options(sp)
    sp.set_defaults(fn=main)
    return sp


def _add_output_options(sp: Any) -> None:
    """``compare``'s options for where it writes and what it shows (a group of ``--help``)."""
    out = sp.add_argument_group("where it writes, what it shows")
    out.add_argument("--out", help="output folder (default runs/<name>/compare-<run-id>)")
    out.add_argument(
        "--cache-dir", help="shared artifact cache (default: the project's, see docs/cache.md)"
    )
    out.add_argument(
        "--metrics",
        action="append",
        default=[],
        metavar="PATTERN",
        help="metric columns to print and plot, shell-style, comma-separated (z_*,'*rms*'); "
        "repeatable; "
        "default all (compare.csv always has all)",
    )
    out.add_argument(
        "--best",
        metavar="METRIC[:max|:abs]",
        help="show the row with the lowest (:max the highest, :abs the closest to zero) METRIC in "
        "bold green, among the variants that ran to the end",
    )
    out.add_argument("--no-plots", action="store_true", help="do not write metrics.png")
    out.add_argument("--json", action="store_true", help="print compare.json instead of the table")


def main(args: Any) -> int:
    """Run ``stereograph compare`` from parsed arguments; 0 when every variant ran, 1 otherwise."""
    from stereograph.app.console import console
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
            with CompareBars(con) as prog:
                res = compare(args.pipeline, args.vary, args.out, progress=prog, **kw)
        else:
            with CompareLines(sys.stderr) as prog:
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
        res.files.update(write_plots(res, patterns))
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
