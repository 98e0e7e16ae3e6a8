"""The comparison in the terminal: rich tables, one row per variant, one column per metric, split
into several tables when the metrics do not fit the width.

Public: :func:`print_table`, :func:`select_metrics`.
"""

from __future__ import annotations

import fnmatch
from pathlib import Path
from typing import Any

from stereograph.app.compare_result import CompareResult, metric_cell, metric_header
from stereograph.app.ranking import PER_PAIR, best_row, is_best, show
from stereograph.core.errors import UsageError


def select_metrics(names: list[str], patterns: list[str] | None) -> list[str]:
    """The names matching any of the shell-style patterns (``z_*``, ``*rms*``), in ``names``'s
    order; all for None."""
    if not patterns:
        return list(names)
    return [n for n in names if any(fnmatch.fnmatchcase(n, p) for p in patterns)]


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
        w = col_width(metric_header(name), [metric_cell(name, r.get(name)) for r in res.rows])
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
    from stereograph.app.console import console as safe_console

    con = console or safe_console(highlight=False)
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
    chunks = _chunks(res, res.varying_keys(), names, con.width, narrow)
    for i, chunk in enumerate(chunks):
        part = f" ({i + 1}/{len(chunks)})" if len(chunks) > 1 else ""
        con.print(_table(res, chunk, names, top, narrow, part))
    _print_below(con, res, names, [n for n in constant if n not in names], top)
    if mistakes:
        raise mistakes[0]


def _table(
    res: CompareResult, chunk: list[str], names: list[str], top: Any, narrow: bool, part: str
) -> Any:
    """One rich table: the varied settings, the metrics of ``chunk``, and a mark column (best,
    FAILED) when there is something to mark."""
    from rich import box
    from rich.markup import escape
    from rich.table import Table

    keys, fixed = res.varying_keys(), res.fixed_settings()
    title = (
        f"compare {Path(res.pipeline).name}"
        + (f" — split {res.split}" if res.split else "")
        + (f"; fixed: {', '.join(fixed)}" if fixed else "")
        + part
    )
    t = Table(
        title=escape(title),
        title_justify="left",
        **({"box": box.SIMPLE_HEAD, "pad_edge": False} if narrow else {}),
    )
    for k in keys:
        t.add_column(escape(k), no_wrap=True)
    for name in chunk:
        t.add_column(metric_header(name), justify="right", no_wrap=True)
    marks = top is not None or any(not r["ok"] for r in res.rows)
    if marks:  # (the colour alone is lost in a log or a pipe)
        t.add_column("", no_wrap=True)
    for r in res.rows:
        cells = [escape(show(r["settings"][k])) for k in keys]
        marked = is_best(top, r)
        mark = (
            [f"<- best {top[0]}" if marked else "" if r["ok"] else "FAILED (see below)"]
            if marks
            else []
        )
        if not r["ok"] and not any(
            isinstance(r.get(n), (int, float)) for n in names if n != PER_PAIR
        ):
            t.add_row(*cells, *(["–"] * len(chunk)), *mark, style="red")
            continue
        style = "bold green" if marked else ("red" if not r["ok"] else None)
        t.add_row(*cells, *(metric_cell(n, r.get(n)) for n in chunk), *mark, style=style)
    return t


def _print_below(con: Any, res: CompareResult, shown: list[str], same: list[str], top: Any) -> None:
    """Under the tables: the metrics every variant has alike, failed and left-out variants, why a
    shown per-pair time is missing, and a note when --best's lowest value of a signed metric is
    the most negative."""
    from rich.markup import escape

    # (not columns: a number that does not change tells nothing apart; compare.csv has them all)
    if same:
        con.print("the same in every variant: " + res.same_in_every(same), markup=False)
    for vr in res.variants:
        if not vr.ok:
            con.print(f"[red]variant {escape(vr.variant.label)} failed:[/] {escape(str(vr.error))}")
    for label, why in res.skipped:
        con.print(f"left out (--skip-invalid): {label}: {why}", markup=False)
    if PER_PAIR in shown and any(r["ok"] and r.get(PER_PAIR) is None for r in res.rows):
        # (a column of dashes would otherwise leave the reader guessing)
        con.print(
            f"{metric_header(PER_PAIR)} –: a per-item node's results came from the cache, stored "
            "by a run that no compare timed; a compare with a new --cache-dir times every node",
            markup=False,
        )
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
