"""The cycles section of ``report.html`` for a ``run --repeat`` loop, from ``run.json`` and
``cycles.jsonl``.

Outcome counts, why the loop stopped, each live node's time per cycle (median, 95th percentile)
and the last cycles' pictures when they were kept (``--save-cycles``). ``cycles.jsonl`` may come
from someone else: only its last :data:`MAX_LOG_BYTES` are read, and every value is escaped.
Public: :func:`cycles_section`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from stereograph.app.page import MIME, Page, escape, table_html

# the tail of cycles.jsonl that is read (a long loop logs a few KB a cycle)
MAX_LOG_BYTES = 8 * 2**20
CYCLES_PICTURED = 30  # the last cycles whose saved pictures are shown


def _tail_records(path: Path) -> list[dict[str, Any]]:
    """The records of the last MAX_LOG_BYTES of a JSON-lines file (a cut first line is dropped)."""
    try:
        with path.open("rb") as f:
            f.seek(max(0, path.stat().st_size - MAX_LOG_BYTES))
            lines = f.read().splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if isinstance(rec, dict):
            out.append(rec)
    return out


def _stage_table(records: list[dict[str, Any]]) -> dict[str, Any]:
    times: dict[str, list[float]] = {}
    for rec in records:
        nodes = rec.get("nodes") if isinstance(rec.get("nodes"), dict) else {}
        for name, d in nodes.items():
            if (
                isinstance(d, dict)
                and d.get("status") == "ran"
                and isinstance(d.get("seconds"), (int, float))
            ):
                times.setdefault(str(name), []).append(float(d["seconds"]) * 1000)
    rows = [
        [n, len(v), round(float(np.median(v)), 1), round(float(np.percentile(v, 95)), 1)]
        for n, v in times.items()
    ]
    return {
        "title": "time per cycle, live nodes",
        "columns": ["node", "cycles", "median (ms)", "p95 (ms)"],
        "rows": rows,
    }


def _pictures(page: Page, run_dir: Path, records: list[dict[str, Any]]) -> str:
    """The saved pictures of the last few cycles (``cycles/<n>/<node>/*.png``), newest first."""
    bits = []
    for rec in reversed(records[-CYCLES_PICTURED:]):
        n = rec.get("cycle")
        if not isinstance(n, int):
            continue
        folder = Path("cycles") / f"{n:05d}"
        try:
            files = sorted(
                str(p.relative_to(run_dir))
                for p in (run_dir / folder).rglob("*")
                if p.suffix.lower() in MIME and p.is_file()
            )
        except OSError:
            continue
        if files:
            bits.append(
                f"<h3>cycle {n}: {escape(rec.get('status'))}</h3>"
                + "".join(page.image(f.replace(os.sep, "/"), f, "item") for f in files[:8])
            )
    return "".join(bits)


def cycles_section(page: Page, loop: dict[str, Any], run_dir: Path) -> str:
    """The loop's section: counts, why it stopped, time per stage, the last cycles' pictures."""
    counts = {
        "cycles": loop.get("cycles"),
        "ok": loop.get("ok"),
        "failed": loop.get("failed"),
        "interrupted": bool(loop.get("interrupted")),
    }
    said = ", ".join(f"{k} <b>{escape(v)}</b>" for k, v in counts.items())
    bits = [
        '<section id="sg-cycles"><h2>cycles</h2>',
        f"<p>{said}; {escape(loop.get('stopped', ''))}</p>",
    ]
    log = loop.get("log") if isinstance(loop.get("log"), str) else "cycles.jsonl"
    if page.inside(log):
        records = _tail_records(run_dir / log)
        failed: dict[str, int] = {}
        for rec in records:
            if rec.get("status") == "failed":
                key = f"{rec.get('failed_node')}: {str(rec.get('error'))[:160]}"
                failed[key] = failed.get(key, 0) + 1
        if failed:
            rows = sorted(([k, v] for k, v in failed.items()), key=lambda r: -r[1])[:5]
            bits.append(
                table_html(
                    {
                        "title": "failed cycles, by reason",
                        "columns": ["node: reason", "cycles"],
                        "rows": rows,
                    }
                )
            )
        if records:
            bits.append(table_html(_stage_table(records)))
            bits.append(_pictures(page, run_dir, records))
        bits.append(f'<p>every cycle: <a href="{escape(log)}">{escape(log)}</a></p>')
    return "\n".join(bits) + "</section>"
