"""``report.html``: one self-contained page per run folder, built from ``run.json`` alone.

Generic: the result (errors, notes, ``Out(headline=True)`` outputs), a loop's cycles, the graph
coloured by status, then one section per node with every file it saved (images embedded, tables
as HTML, markdown as is, the rest linked). No network; an inline script records that every image
decoded (``#sg-images``). Public: :func:`write_report` (``stereograph report RUN_DIR``).
docs/report.md and docs/engine.md ("report.html") say more.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from stereograph.app import graph_picture
from stereograph.app.page import (
    CHECK,
    MIME,
    STYLE,
    Page,
    ascii_only,
    escape,
    href,
    link,
    not_shown,
    path_parts,
    table_html,
    write_html,
)

REPORT_NAME = "report.html"
# per-item image folders (120 overlays): the first ones embedded, the rest linked
IMAGES_PER_OUTPUT = 6
# warnings per node on the page (a hard set warns for dozens of pairs); the rest stay in run.json
MESSAGES_SHOWN = 20


def _group(files: list[str]) -> dict[str, list[str]]:
    """Files by output: ``node/out.png`` -> ``out``; ``node/out/item.png`` -> ``out``."""
    groups: dict[str, list[str]] = {}
    for f in files:
        parts = path_parts(f)
        key = parts[1] if len(parts) > 2 else os.path.splitext(parts[-1])[0]
        groups.setdefault(key, []).append(f)
    return groups


def node_section(page: Page, n: dict[str, Any]) -> str:
    name, status = n.get("node", "?"), n.get("status", "?")
    items = n.get("items") or 0
    bits = [
        f'<h2 id="node-{escape(name)}">{escape(name)} <small>({escape(n.get("type", ""))})</small> '
        f'<span class="st st-{escape(str(status).replace(" ", ""))}">{escape(status)}</span></h2>',
        f"<p>{float(n.get('seconds') or 0):.2f} s"
        + (
            f"; {escape(items)} items ({escape(n.get('items_ran', 0))} computed, "
            f"{escape(n.get('items_failed', 0))} failed)"
            if items
            else ""
        )
        + "</p>",
    ]
    if n.get("error"):
        bits.append(f'<p class="err">{escape(n["error"])}</p>')
    if n.get("hint"):
        bits.append(f'<p class="hint">Fix: {escape(n["hint"])}</p>')
    messages = n.get("messages") or []
    for m in messages[:MESSAGES_SHOWN]:
        bits.append(f'<p class="hint">{escape(m)}</p>')
    if len(messages) > MESSAGES_SHOWN:  # say that the list goes on, and where
        bits.append(
            f'<p class="hint">&#8230; and {len(messages) - MESSAGES_SHOWN} more messages in '
            f'<a href="run.json">run.json</a></p>'
        )
    heads = n.get("headline") if isinstance(n.get("headline"), list) else []
    for out, files in _group([f for f in n.get("files", []) if isinstance(f, str)]).items():
        bits.append(
            f'<p><a href="#sg-result">{escape(out)}</a>: in the result above</p>'
            if out in heads
            else output_block(page, out, files)
        )
    return "\n".join(bits)


def output_block(
    page: Page, out: str, files: list[str], title: str | None = None, small_json: bool = False
) -> str:
    """One output's files: pictures (per-item ones folded: the first few, then a link to the
    folder), tables and Markdown rendered, the rest linked; ``small_json`` shows a short JSON value
    as text."""
    imgs = [f for f in files if os.path.splitext(f)[1].lower() in MIME]
    rest = [f for f in files if f not in imgs]
    bits = [f'<div class="sg-output" data-output="{escape(out)}"><h3>{escape(title or out)}</h3>']
    per_item = len(path_parts(imgs[0])) > 2 if imgs else False
    fold = per_item and len(imgs) > 1  # a picture per item: folded, so that the page stays short
    if fold:
        bits.append(f"<details><summary>{len(imgs)} pictures, one per item</summary>")
    bits += [page.image(f, f, "item" if per_item else "") for f in imgs[:IMAGES_PER_OUTPUT]]
    if len(imgs) > IMAGES_PER_OUTPUT:
        folder = Path(imgs[0]).parent.as_posix()
        bits.append(
            f"<p>&#8230; and {len(imgs) - IMAGES_PER_OUTPUT} more in "
            f'<a href="{href(folder)}">{escape(folder)}</a></p>'
        )
    if fold:
        bits.append("</details>")
    for f in rest:
        bits.append(
            page.json_block(f, small_json)
            if f.endswith(".json")
            else link(f)
            if page.inside(f)
            else not_shown(f)
        )
    bits.append("</div>")
    return "\n".join(bits)


def result_section(page: Page, nodes: list[dict[str, Any]]) -> str:
    """The answer first: what failed, the one-line summaries nodes gave (a calibration's RMS), and
    the outputs nodes declare as the run's headline (``Out(headline=True)``), in data-flow order."""
    bits = ['<section id="sg-result"><h2>result</h2>']
    for n in nodes:
        if n.get("error"):
            bits.append(
                f'<p class="err">{escape(n.get("node"))} ({escape(n.get("type"))}): '
                f"{escape(n['error'])}</p>"
            )
    said = [
        [n.get("node"), n["messages"][0]]
        for n in nodes
        if isinstance(n.get("messages"), list) and len(n["messages"]) == 1 and not n.get("error")
    ]
    if said:
        bits.append(
            table_html(
                {"title": "what the nodes said", "columns": ["node", "note"], "rows": said},
                "sg-notes",
            )
        )
    # pictures first, side by side with the tables: the answer fits a laptop's first screen
    blocks = []
    for n in nodes:
        heads = n.get("headline") if isinstance(n.get("headline"), list) else []
        groups = _group([f for f in n.get("files", []) if isinstance(f, str)])
        for out in [o for o in heads if o in groups]:
            pictures = any(os.path.splitext(f)[1].lower() in MIME for f in groups[out])
            blocks.append(
                (
                    not pictures,
                    output_block(page, out, groups[out], f"{n.get('node')}: {out}", True),
                )
            )
    if blocks:
        bits.append(
            '<div class="sg-headline">'
            + "".join(b for _, b in sorted(blocks, key=lambda b: b[0]))
            + "</div>"
        )
    if len(bits) == 1:
        bits.append(
            "<p>No node of this pipeline declares a headline output: see the nodes below.</p>"
        )
    return "\n".join(bits) + "</section>"


def _contents(nodes: list[dict[str, Any]]) -> str:
    """Links to the nodes that saved pictures or tables (a long page: 120 overlays, a dozen
    nodes)."""
    links = [
        f'<li><a href="#node-{escape(n["node"])}">{escape(n["node"])}</a>: '
        + ", ".join(
            sorted(
                {escape(k) for k in _group([f for f in n.get("files", []) if isinstance(f, str)])}
            )
        )
        + "</li>"
        for n in nodes
        if n.get("files") and "node" in n
    ]
    return f"<h3>outputs</h3><ul>{''.join(links)}</ul>" if links else ""


def flow_order(nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Nodes in data-flow order (each after the nodes it reads), otherwise as listed.

    run.json lists nodes as the pipeline file (and its includes) define them, so a node that an
    including file rewires can come before its inputs; the page reads top to bottom like the graph.
    """
    by_name = {n.get("node"): n for n in nodes}
    desc = {
        name: {"inputs": n.get("inputs") if isinstance(n.get("inputs"), dict) else {}}
        for name, n in by_name.items()
    }
    index = {name: i for i, name in enumerate(by_name)}
    order = graph_picture.topological_order(graph_picture.dag(desc), index.__getitem__)
    return [by_name[name] for name in order] + [
        n for n in nodes if by_name.get(n.get("node")) is not n
    ]


def build_html(summary: dict[str, Any], run_dir: Path) -> str:
    page = Page(run_dir)
    nodes = flow_order([n for n in summary.get("nodes", []) if isinstance(n, dict)])
    title = f"{Path(str(summary.get('pipeline', 'run'))).name} — run {summary.get('run_id', '')}"
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{escape(title)}</title>",
        f"<style>{STYLE}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
        f"<p>pipeline <code>{escape(summary.get('pipeline', ''))}</code>; result: "
        f"<b>{'ok' if summary.get('ok') else 'FAILED'}</b>"
        + (
            f"; overrides: <code>{escape(' '.join(summary.get('overrides') or []))}</code>"
            if summary.get("overrides")
            else ""
        )
        + "</p>",
        '<p id="sg-images" data-ok="unknown">image check did not run</p>',
    ]
    for note in summary.get("notes") or []:
        parts.append(f'<p class="hint">note: {escape(note)}</p>')
    parts.append(result_section(page, nodes))
    if isinstance(summary.get("loop"), dict):
        from stereograph.app import report_cycles

        parts.append(report_cycles.cycles_section(page, summary["loop"], run_dir))
    parts.append(_graph_and_overview(nodes))
    for n in nodes:
        parts.append(
            f'<section class="sg-node-section" data-node="{escape(n.get("node", ""))}">'
            f"{node_section(page, n)}</section>"
        )
    parts.append(CHECK + "</body></html>")
    return "\n".join(parts)


def _graph_and_overview(nodes: list[dict[str, Any]]) -> str:
    """The "graph and nodes" block: the DAG coloured by status, beside a table of every node."""
    desc = {
        n["node"]: {
            "type": n.get("type", ""),
            "mapped": bool(n.get("mapped")),
            "inputs": n.get("inputs") or {},
        }
        for n in nodes
        if "node" in n
    }
    status = {n["node"]: n.get("status", "") for n in nodes if "node" in n}
    overview = {
        "title": "nodes",
        "columns": ["node", "type", "status", "seconds", "items", "error"],
        "rows": [
            [
                n.get("node"),
                n.get("type"),
                n.get("status"),
                round(float(n.get("seconds") or 0), 3),
                n.get("items") or "",
                n.get("error") or "",
            ]
            for n in nodes
        ],
    }
    svg = ascii_only(graph_picture.to_svg(desc, status))
    return (
        f'<h2 id="sg-details">graph and nodes</h2><div class="graph-row">'
        f'<div class="graph" id="sg-graph">{svg}</div>'
        f"<div>{table_html(overview, 'sg-overview')}{_contents(nodes)}</div></div>"
    )


def write_report(run_dir: str | Path) -> Path:
    """(Re)build ``RUN_DIR/report.html`` from ``RUN_DIR/run.json``; returns its path.

    Raises :class:`~stereograph.core.errors.ConfigError` when the folder holds no readable
    ``run.json``.
    """
    from stereograph.core.errors import ConfigError

    d = Path(run_dir)
    try:
        summary = json.loads((d / "run.json").read_text())
        if not isinstance(summary, dict):
            raise ValueError("not a JSON object")
    except FileNotFoundError:
        raise ConfigError(
            f"{d} has no run.json: it is not the folder of a stereograph run",
            hint="give the folder a run wrote (printed as 'outputs:' at the end of "
            "`stereograph run`)",
        ) from None
    except (OSError, ValueError) as e:
        raise ConfigError(
            f"cannot read {d / 'run.json'}: {e}", hint="run the pipeline again to rewrite it"
        ) from None
    try:
        page = build_html(summary, d)
    # a hand-edited or foreign run.json
    except (TypeError, AttributeError, KeyError, ValueError) as e:
        raise ConfigError(
            f"{d / 'run.json'} is not in the form stereograph writes ({type(e).__name__}: {e})",
            hint="give the folder a run wrote, or run the pipeline again to rewrite it",
        ) from None
    return write_html(d / REPORT_NAME, page)
