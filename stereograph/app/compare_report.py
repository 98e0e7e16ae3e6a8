"""``compare.html``: one self-contained page for ``stereograph compare``.

The table of every variant (its full override set in a column, and the settings every variant
shares -- the pipeline's own ``--set`` overrides and the fixed variant keys -- in the table's
title), the comparison plots embedded, and a link to each variant's own ``report.html``. Built
from the :class:`~stereograph.app.compare_result.CompareResult` only: its columns are the metrics
the variants' nodes declared (``Out("Metrics")``), whatever they are; the engine knows nothing of
them.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from stereograph.app.compare_result import CompareResult, metric_cell, metric_header
from stereograph.app.page import CHECK, STYLE, Page, table_html, write_html
from stereograph.app.ranking import best_row, is_best, show
from stereograph.core.errors import UsageError

COMPARE_NAME = "compare.html"


# metric columns in the first table (a 1280 px window); the others that vary follow
MAIN_COLUMNS = 10


def compare_table(
    res: CompareResult, overrides: list[str], names: list[str] | None = None
) -> dict[str, Any]:
    """The comparison as a *table* value (page.table_html renders it): one column per metric in
    ``names`` (default: the ranked one, then those that differ between variants)."""
    varying, fixed = res.varying_keys(), res.fixed_settings()
    split = f", split {res.split}" if res.split else ""
    title = (
        f"compare {Path(res.pipeline).name}: {len(res.variants)} variants{split}. Every variant: "
        + ("; ".join([f"--set {o}" for o in overrides] + fixed) or "no other overrides")
        + f". Varied: {', '.join(varying)}."
    )
    names = names if names is not None else res.shown_metrics()[0]
    cols = ["variant", "ok"] + [metric_header(n) for n in names] + ["report"]
    try:
        top = best_row(res, res.ranked_by)
    # a metric no variant declared: the CLI's table says so; the page marks nothing
    except UsageError:
        top = None
    rows = []
    for r, vr in zip(res.rows, res.variants):
        label = res.short_label(vr.variant)
        cells = [
            label + (f" (best {top[0]})" if is_best(top, r) else ""),
            "yes" if r.get("ok") else "NO",
        ]
        cells += [metric_cell(n, r.get(n), missing="") for n in names]
        cells.append(
            str(Path("variants") / vr.out_dir.name / "report.html")
            if vr.out_dir is not None
            else ""
        )
        rows.append(cells)
    return {"title": title, "columns": cols, "rows": rows}


def settings_table(res: CompareResult, overrides: list[str]) -> dict[str, Any]:
    """Each variant's full settings (the --set overrides and its varied keys), and the metrics every
    variant has the same value of: below the main table, which keeps to what tells variants
    apart."""
    _, constant = res.shown_metrics()
    rows = [
        [
            ", ".join(show(v) for v in vr.variant.settings.values()),
            " ".join(
                [f"--set {o}" for o in overrides]
                + [f"{k}={show(v)}" for k, v in vr.variant.settings.items()]
            ),
        ]
        for vr in res.variants
    ]
    if constant and res.rows:
        rows.append(["(every variant)", res.same_in_every(constant)])
    return {
        "title": "full settings of each variant, and the metrics that do not change",
        "columns": ["variant", "settings"],
        "rows": rows,
    }


def write_compare_html(res: CompareResult, overrides: list[str] | None = None) -> Path:
    """Write ``compare.html`` into ``res.out_dir``; returns its path."""
    out: Path = res.out_dir
    page = Page(out)
    shown = res.shown_metrics()[0]
    tables = [compare_table(res, list(overrides or []), shown[:MAIN_COLUMNS])]
    if shown[MAIN_COLUMNS:]:
        more = compare_table(res, list(overrides or []), shown[MAIN_COLUMNS:])
        tables.append({**more, "title": "more metrics that differ between variants"})
    body = "".join(table_html(t, "sg-compare") for t in tables)
    for link in {r[-1] for r in tables[0]["rows"] if r[-1]}:  # the report column as links
        body = body.replace(
            f"<td>{html.escape(link)}</td>",
            f'<td><a href="{html.escape(link)}">variant report</a></td>',
        )
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>compare {html.escape(Path(res.pipeline).name)}</title><style>{STYLE}"
        ".sg-compare{font-size:.82em}.sg-compare td,.sg-compare th{padding:2px 5px}"
        ".sg-compare caption{font-weight:normal}</style></head><body>",
        f"<h1>compare {html.escape(Path(res.pipeline).name)}</h1>",
        '<p id="sg-images" data-ok="unknown">image check did not run</p>',
        body,
        table_html(settings_table(res, list(overrides or [])), "sg-settings"),
    ]
    for vr in res.variants:
        if not vr.ok:
            parts.append(
                f'<p class="err">variant {html.escape(vr.variant.label)} failed: '
                f"{html.escape(str(vr.error))}</p>"
            )
    for label, why in res.skipped:
        parts.append(
            f'<p class="err">left out (its settings do not validate): {html.escape(label)}: '
            f"{html.escape(why)}</p>"
        )
    for name, path in (res.files or {}).items():
        p = Path(path)
        if p.suffix.lower() in (".png", ".svg"):
            parts.append(
                f"<h2>{html.escape(name.replace('_', ' '))}</h2>"
                # a panel per metric: full width
                + page.image(str(p.relative_to(out)), p.name, "wide")
            )
    parts.append(CHECK + "</body></html>")
    return write_html(out / COMPARE_NAME, "\n".join(parts))
