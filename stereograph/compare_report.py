"""``compare.html``: one self-contained page for ``stereograph compare``.

The table of every variant (its full override set in a column, and the settings every variant
shares -- the pipeline's own ``--set`` overrides and the fixed variant keys -- in the table's
title), the comparison plots embedded, and a link to each variant's own ``report.html``.
Built from the :class:`~stereograph.compare.CompareResult` only: its columns are the metrics the
variants' nodes declared (``Out("Metrics")``), whatever they are; the engine knows nothing of them.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from stereograph.report import _CHECK, _STYLE, _Page, table_html, write_html

COMPARE_NAME = "compare.html"


def _fmt(v: Any, digits: int = 3) -> str:
    return "" if v is None else (f"{v:.{digits}f}" if isinstance(v, float) else str(v))


def compare_table(res: Any, overrides: list[str]) -> dict[str, Any]:
    """The comparison as a *table* value (report.table_html renders it): one column per declared metric."""
    from stereograph.compare import PER_PAIR, _show

    varying = [k for k in res.keys if len({_show(v.variant.settings[k]) for v in res.variants}) > 1] or res.keys
    fixed = [f"{k}={_show(res.variants[0].variant.settings[k])}" for k in res.keys if k not in varying]
    split = f", split {res.split}" if res.split else ""
    title = (f"compare {Path(res.pipeline).name}: {len(res.variants)} variants{split}. Every variant: "
             + ("; ".join([f"--set {o}" for o in overrides] + fixed) or "no other overrides")
             + f". Varied: {', '.join(varying)}.")
    names = list(res.metric_names)
    cols = ["variant", "full settings (--set and varied keys)", "ok"]
    cols += ["pair ms" if n == PER_PAIR else n for n in names] + ["report"]
    rows = []
    for r, vr in zip(res.rows, res.variants):
        cells = [", ".join(_show(vr.variant.settings[k]) for k in varying),
                 " ".join([f"--set {o}" for o in overrides]
                          + [f"{k}={_show(v)}" for k, v in vr.variant.settings.items()]),
                 "yes" if r.get("ok") else "NO"]
        for n in names:
            v = r.get(n)
            cells.append("" if v is None else (f"{1000 * v:.1f}" if n == PER_PAIR else _fmt(v, 4)))
        cells.append(str(Path("variants") / vr.out_dir.name / "report.html") if vr.out_dir is not None else "")
        rows.append(cells)
    return {"title": title, "columns": cols, "rows": rows}


def write_compare_html(res: Any, overrides: list[str] | None = None) -> Path:
    """Write ``compare.html`` into ``res.out_dir``; returns its path."""
    out: Path = res.out_dir
    page = _Page(out)
    table = compare_table(res, list(overrides or []))
    body = table_html(table, "sg-compare")
    for link in {r[-1] for r in table["rows"] if r[-1]}:  # the report column as links
        body = body.replace(f"<td>{html.escape(link)}</td>",
                            f'<td><a href="{html.escape(link)}">variant report</a></td>')
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'>",
             f"<title>compare {html.escape(Path(res.pipeline).name)}</title><style>{_STYLE}</style></head><body>",
             f"<h1>compare {html.escape(Path(res.pipeline).name)}</h1>",
             '<p id="sg-images" data-ok="unknown">image check did not run</p>', body]
    for vr in res.variants:
        if not vr.ok:
            parts.append(f'<p class="err">variant {html.escape(vr.variant.label)} failed: '
                         f"{html.escape(str(vr.error))}</p>")
    for label, why in res.skipped:
        parts.append(f'<p class="err">left out (its settings do not validate): {html.escape(label)}: '
                     f"{html.escape(why)}</p>")
    for name, path in (res.files or {}).items():
        p = Path(path)
        if p.suffix.lower() in (".png", ".svg"):
            parts.append(f"<h2>{html.escape(name.replace('_', ' '))}</h2>"
                         + page.image(str(p.relative_to(out)), p.name, "wide"))  # a panel per metric: full width
    parts.append(_CHECK + "</body></html>")
    return write_html(out / COMPARE_NAME, "\n".join(parts))
