"""What a comparison writes: its folder (refusing one that is not an earlier comparison's),
``compare.csv``, ``compare.json``, ``metrics.png``, and the outputs of a variant's own nodes.

Every file is written whole or not at all. Public: :data:`MARKER`, :func:`prepare_compare_dir`,
:func:`write_tables`, :func:`write_plots`, :func:`write_variant_outputs`.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from stereograph.app.compare_result import CompareResult
from stereograph.app.compare_table import select_metrics
from stereograph.app.ranking import PER_PAIR
from stereograph.app.variants import Variant
from stereograph.core import run_folder
from stereograph.core.errors import ConfigError
from stereograph.core.graph import Graph
from stereograph.core.outputs import write_whole

# a compare.json key only stereograph writes: the folder holds its comparison
MARKER = "stereograph_compare"


def _compare_folder(out: Path) -> bool:
    """Whether ``out`` holds an earlier comparison: its ``compare.json`` (with :data:`MARKER`, or of
    the shape older versions wrote), or -- one that was interrupted before writing it -- only
    ``variants/`` of run folders that stereograph wrote."""
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
            marker = run_folder.MARKER
            run = json.loads((v / "run.json").read_text()) if any(v.iterdir()) else {marker: {}}
            if not (isinstance(run, dict) and isinstance(run.get(marker), dict)):
                return False
    except (OSError, ValueError):
        return False
    return True


def prepare_compare_dir(out: Path) -> None:
    """Make ``out`` ready for a comparison's files, or refuse it (:class:`ConfigError`): an existing
    file, a folder that cannot be made or written, a non-empty folder that is not an earlier
    comparison's (its files are never overwritten: ``compare.csv``, ``variants/``)."""
    run_folder.check_folder_path(out)
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


def write_tables(
    res: CompareResult, skipped: list[tuple[Variant, str]], plots: bool
) -> dict[str, Path]:
    """``compare.csv`` and ``compare.json`` (and ``metrics.png`` with ``plots``); returns them by
    kind."""
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
        files.update(write_plots(res))
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


def _plotted(res: CompareResult, names: list[str]) -> list[str]:
    """The chosen metrics with a number in at least one variant."""
    return [n for n in names if any(isinstance(r.get(n), (int, float)) for r in res.rows)]


def write_plots(res: CompareResult, patterns: list[str] | None = None) -> dict[str, Path]:
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
    labels = [res.short_label(vr.variant) for vr in res.variants]
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
    fig.suptitle(f"compare {Path(res.pipeline).name}: " + ", ".join(res.varying_keys()), fontsize=9)
    fig.tight_layout()
    path = res.out_dir / "metrics.png"
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    write_whole(path, buf.getvalue())
    return {"metrics": path}


def write_variant_outputs(graph: Graph, result: Any, own: set[str]) -> None:
    """The outputs of the given nodes (the variant's own: what it shares with the first variant is
    written there) and ``run.json`` into its folder, as a run writes them."""
    result.state.add_to_summary("outputs_of", sorted(own))
    run_folder.write_run_outputs(graph, result.state, result, [n for n in graph.order if n in own])
