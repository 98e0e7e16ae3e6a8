"""What ``stereograph run`` prints at the end: the small terminal outputs (a location, joint
angles), the table of nodes, their further notes; rich on a terminal, plain text in a log or pipe.

Public: :func:`echo_entries`, :func:`rendered_markdown`, :func:`print_closing`, :func:`clip`,
:func:`load_printing`, :data:`SUMMARY_COLUMNS`.
"""

from __future__ import annotations

import json
import sys
from typing import Any

from stereograph.app.console import PIPE_WIDTH, command_console, echo_entry

SUMMARY_COLUMNS = ("node", "type", "status", "items", "seconds", "note")


def _summary_rows(result) -> list[list[str]]:
    """The run summary's rows, plain text (SUMMARY_COLUMNS)."""
    rows = []
    for r in result.reports.values():
        items = (
            ""
            if not r.items
            else (
                f"{r.items_ran} ran / {r.items}"
                + (f", {r.items_failed} failed" if r.items_failed else "")
            )
        )
        if r.error:
            note = r.error + (
                f" (+{r.items_failed - 1} more failed items: run.json)"
                if r.items_failed > 1
                else ""
            )
        elif r.messages:
            more = len(r.messages) - 1
            note = clip(r.messages[0], 90) + (f" (+{more} more below)" if more else "")
        else:
            note = ""
        rows.append([r.name, r.type, r.status, items, f"{r.seconds:.2f}", clip(note, 160)])
    return rows


def clip(text: str, n: int) -> str:
    """``text`` in at most ``n`` characters, cut after a whole word and marked '…' (the whole
    text is in run.json, and an error's under the table)."""
    if len(text) <= n:
        return text
    cut = text[: n - 1]
    space = cut.rfind(" ")
    return (cut[:space] if space > n // 2 else cut).rstrip(" ,;:(") + "…"


ECHO_LIMIT = 6  # small terminal values echoed after a run


# a node's further messages printed under the table (a per-item node may have dozens)
NOTES_PER_NODE = 3


def _more_notes(result) -> list[str]:
    """A node's messages after the first (the table's note column shows the first): a warning such
    as 'rejected 1 view(s): 03' must not be only in run.json."""
    lines = []
    for r in result.reports.values():
        rest = [] if r.error else r.messages[1:]
        for m in rest[:NOTES_PER_NODE]:
            lines.append(f"note: {r.name}: {m}")
        if len(rest) > NOTES_PER_NODE:
            lines.append(f"note: {r.name}: +{len(rest) - NOTES_PER_NODE} more in run.json")
    return lines


def _summary_table(result, con) -> None:
    from rich.markup import escape
    from rich.table import Table

    colours = {
        "ran": "green",
        "cached": "cyan",
        "failed": "red",
        "partial": "yellow",
        "skipped": "magenta",
        "not selected": "dim",
    }
    t = Table(*SUMMARY_COLUMNS, title=f"run {result.run_id}", title_justify="left")
    for name, type_, status, items, seconds, note in _summary_rows(result):
        t.add_row(
            escape(name),
            escape(type_),
            f"[{colours.get(status, 'white')}]{status}[/]",
            items,
            seconds,
            escape(note),
        )
    con.print(t)


def _plain_closing(echo: list, result, loop, width: int) -> str | None:
    """What :func:`_print_echo`, :func:`_summary_table` and the last lines print, as plain text
    for a console that is not a terminal (stereograph.app.plaintext); None where rich must lay it
    out."""
    from stereograph.app import plaintext

    parts: list[str | None] = []
    for title, kind, text, *pre in [e for e in echo if e[0] != "live"][:ECHO_LIMIT]:
        parts.append(plaintext.rule(title, width))
        if pre and pre[0].get("console") == [width, None]:
            parts.append(pre[0]["text"].removesuffix("\n"))
        elif kind == "json":
            parts.append(plaintext.pretty(json.loads(text), width))
        else:
            return None
    parts.append(
        plaintext.table(f"run {result.run_id}", list(SUMMARY_COLUMNS), _summary_rows(result), width)
    )
    parts += [plaintext.line(n) for n in _more_notes(result)]
    if loop is not None:
        parts.append(
            plaintext.line(
                f"loop: {loop.summary()}; every cycle is in {result.out_dir / 'cycles.jsonl'}"
            )
        )
    parts.append(plaintext.line(f"outputs: {result.out_dir}"))
    if (result.out_dir / "report.html").is_file():
        parts.append(plaintext.line(f"report: {result.out_dir / 'report.html'}"))
    return None if None in parts else "\n".join(parts) + "\n"


def echo_entries(result, live: frozenset[str] = frozenset()) -> list[list[str]]:
    """``[title, kind, text]`` of the small terminal outputs, in order; ``["live", node, output]``
    for those of the nodes in ``live`` (a rerun memo fills them in when they run again)."""
    entries: list[list[str]] = []
    for node, out, item in list(result.values):
        if node not in result.terminal or item is not None:
            continue  # (decided before loading: a cached rerun reads only what it shows)
        if node in live:
            entries.append(["live", node, out])
            continue
        shown = echo_entry(result.values[(node, out, item)])
        if shown is not None:
            entries.append([f"{node}.{out}", *shown])
            if sum(e[0] != "live" for e in entries) >= ECHO_LIMIT:
                break
    return entries


def rendered_markdown(entries: list[list[str]], con) -> list[list[Any]]:
    """The entries with each text also as ``con`` renders it (its width and colours): a replayed
    rerun on the same kind of console prints that without parsing the Markdown or laying out the
    data again."""
    out: list[list[Any]] = []
    for e in entries:
        if e[0] != "live":
            with con.capture() as cap:
                _print_entry(con, e[1], e[2])
            e = [*e[:3], {"console": [con.width, con.color_system], "text": cap.get()}]
        out.append(e)
    return out


def _print_echo(entries: list[list[Any]], con) -> None:
    """Print the small terminal outputs (a location, joint angles, servo commands) for the user;
    larger ones are only in the output folder."""
    from rich.markup import escape

    for title, kind, text, *pre in [e for e in entries if e[0] != "live"][:ECHO_LIMIT]:
        con.rule(escape(title), align="left")
        if pre and pre[0].get("console") == [con.width, con.color_system]:
            con.file.write(pre[0]["text"])
        else:
            _print_entry(con, kind, text)


def load_printing() -> None:
    """What printing a run's results imports (~0.15 s): loaded while a --workers run waits for its
    pool (run_graph's ``prepare``), not alone at its end."""
    import rich.markdown  # noqa: F401
    import rich.pretty  # noqa: F401
    import rich.table  # noqa: F401


def _print_entry(con, kind: str, text: str) -> None:
    if kind == "markdown":
        from rich.markdown import Markdown

        from stereograph.core.errors import printable

        con.print(Markdown(printable(text)))
    else:
        from rich.pretty import Pretty

        con.print(Pretty(json.loads(text), indent_guides=False, max_string=200))


def print_closing(echo: list, result: Any, loop: Any = None) -> None:
    """Print the echoed outputs, the table of nodes, their notes, the loop's line and where the
    outputs are: plain text in a log or pipe, rich on a terminal."""
    from stereograph.app import plaintext

    width = plaintext.plain_width(sys.stdout, PIPE_WIDTH)
    plain = _plain_closing(echo, result, loop, width) if width else None
    if plain is not None:  # (a log or pipe: rich would print the same, without colours)
        sys.stdout.write(plain)
        sys.stdout.flush()
    else:
        from rich.markup import escape

        con = command_console()
        _print_echo(echo, con)
        _summary_table(result, con)
        for n in _more_notes(result):
            con.print(n, markup=False, highlight=False)
        if loop is not None:
            con.print(
                escape(
                    f"loop: {loop.summary()}; every cycle is in {result.out_dir / 'cycles.jsonl'}"
                )
            )
        con.print(f"outputs: {result.out_dir}", markup=False)
        if (result.out_dir / "report.html").is_file():
            con.print(f"report: {result.out_dir / 'report.html'}", markup=False)
