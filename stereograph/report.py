"""``report.html``: one self-contained page per run folder, built from ``run.json`` alone.

The engine knows no domain, so the page is generic: first the result (errors, the nodes' one-line
notes, the outputs nodes declare ``Out(headline=True)``), a loop's cycles, then the pipeline graph
(coloured by status) and one section per node with its status, time, items, errors and every file
the node saved -- images
(PNG, SVG, JPEG) embedded as data URIs, *tables* rendered as HTML, ``markdown`` text shown as is,
anything else linked. What a kind of node shows is therefore up to the node: it declares a saved
``Image`` output (a figure it drew) or a saved *table* value::

    {"title": str, "columns": [str, ...], "rows": [[cell, ...], ...]}

No network: no scripts or styles from elsewhere. A small inline script checks that every image
decoded and writes the result into the page (``#sg-images``, ``data-ok``), which the browser test
reads from Chromium's ``--dump-dom``. ``stereograph report RUN_DIR`` rebuilds the page.
"""

from __future__ import annotations

import base64
import html
import json
import os
import re
import urllib.parse
import uuid
from pathlib import Path
from typing import Any

import networkx as nx

from stereograph import graph_picture

REPORT_NAME = "report.html"
IMAGES_PER_OUTPUT = 6  # per-item image folders (120 overlays): the first ones embedded, the rest linked
MESSAGES_SHOWN = 20  # warnings per node on the page (a hard set warns for dozens of pairs); the rest stay in run.json
EMBED_BUDGET_BYTES = 48 * 2**20  # beyond this, images are linked (they lie beside the page) instead of embedded
MAX_JSON_BYTES = 2 * 2**20
SMALL_JSON_BYTES = 4096  # a headline JSON value up to this size is shown as text (a pick's summary)
FIELDS_SHOWN = 10  # ... its first fields
_MIME = {".png": "image/png", ".svg": "image/svg+xml", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}

_STYLE = """
body{font-family:sans-serif;margin:1.2em;color:#222;max-width:1500px}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}
.st{display:inline-block;padding:1px 8px;border-radius:8px;font-size:.85em}
.st-ran{background:#d9f2d9}.st-cached{background:#e3ecfa}.st-partial{background:#fde9c4}
.st-failed{background:#f8d0d0}.st-skipped,.st-notselected{background:#e6e6e6}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}
td,th{border:1px solid #bbb;padding:2px 7px;text-align:right}
th{background:#f0f0f0}
td:first-child,th:first-child{text-align:left}caption{text-align:left;font-weight:bold;padding:3px}
figure{display:inline-block;margin:.4em;vertical-align:top}figcaption{font-size:.8em;color:#555}
figure img{max-width:720px;border:1px solid #ddd}figure.item img{max-width:640px}figure.wide img{max-width:100%}
.graph-row{display:flex;gap:2em;align-items:flex-start;flex-wrap:wrap}.err{color:#a00}.hint{color:#555}
pre{background:#f7f7f7;padding:.5em;overflow-x:auto;font-size:.85em}.graph{overflow-x:auto}
.sg-headline{display:flex;flex-wrap:wrap;gap:0 1.5em;align-items:flex-start}
.sg-headline h3{margin:.3em 0;font-size:1em}.sg-headline figure img{max-width:600px}
#sg-result h2{margin-top:.6em}
"""

_CHECK = """
<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  var el = document.getElementById('sg-images');
  el.setAttribute('data-ok', bad.length === 0 ? 'true' : 'false');
  el.setAttribute('data-loaded', String(imgs.length - bad.length));
  el.setAttribute('data-total', String(imgs.length));
  el.textContent = (imgs.length - bad.length) + ' of ' + imgs.length + ' images loaded' +
    (bad.length ? ' (not loaded: ' + bad.map(function (i) { return i.alt; }).join(', ') + ')' : '');
});
</script>
"""


def _e(x: Any) -> str:
    return _ascii(html.escape(str(x)))


def _ascii(text: str) -> str:
    """Non-ASCII characters as character references: the page is ASCII, so joining and writing its
    megabytes of embedded pictures stays a byte copy (a single "—" would make Python store and
    encode the whole page at two bytes a character)."""
    return text if text.isascii() else text.encode("ascii", "xmlcharrefreplace").decode("ascii")


class _Page:
    def __init__(self, run_dir: Path):
        self.dir = run_dir
        self.budget = EMBED_BUDGET_BYTES
        self._root: str | None = None

    def inside(self, rel: str) -> bool:
        """Whether ``rel`` names a file in the run folder. run.json may come from someone else (a run
        folder handed over, then ``stereograph report``): a path that is absolute, climbs out with
        ``..`` or passes through a symbolic link (stereograph makes none) must not put a file from
        elsewhere on the page -- embedded, it would go wherever the page goes."""
        if not isinstance(rel, str) or not rel or os.path.isabs(rel) or ".." in _parts(rel) or "\0" in rel:
            return False
        if self._root is None:
            self._root = os.path.realpath(self.dir)
        return os.path.realpath(os.path.join(self.dir, rel)) == os.path.join(self._root, *_parts(rel))

    def image(self, rel: str, caption: str, css_class: str = "") -> str:
        """One figure: embedded while the budget lasts, else linked (the file lies beside the page)."""
        p = self.dir / rel
        mime = _MIME.get(p.suffix.lower())
        if not self.inside(rel):
            return _not_shown(rel)
        try:
            size = p.stat().st_size
        except OSError:
            return f'<p class="err">missing file {_e(rel)}</p>'
        if size <= self.budget:
            self.budget -= size
            src = f"data:{mime};base64," + base64.b64encode(p.read_bytes()).decode("ascii")
        else:
            src = _href(rel)
        return (f'<figure class="{css_class}"><img src="{src}" alt="{_e(rel)}" data-file="{_e(rel)}" loading="eager">'
                f"<figcaption>{_e(rel)}</figcaption></figure>")

    def json_block(self, rel: str, small_as_text: bool = False) -> str:
        p = self.dir / rel
        if not self.inside(rel):
            return _not_shown(rel)
        try:
            size = p.stat().st_size
            if size > MAX_JSON_BYTES:
                return _link(rel)
            data = p.read_bytes()
            if small_as_text and size <= SMALL_JSON_BYTES and not (b'"columns"' in data or b'"markdown"' in data):
                rows = _flat_rows(json.loads(data))
                more = f"<p>&#8230; {len(rows) - FIELDS_SHOWN} more fields in</p>" if len(rows) > FIELDS_SHOWN else ""
                return table_html({"columns": ["field", "value"], "rows": rows[:FIELDS_SHOWN]}, "sg-fields") \
                    + more + _link(rel)
            # Only a table or a markdown value is shown: a file without their keys is linked unparsed
            # (json.dumps writes a key's ASCII letters as they are; a run's records are most of its JSON).
            if not ((b'"columns"' in data and b'"rows"' in data) or b'"markdown"' in data):
                return _link(rel)
            value = json.loads(data)
        except (OSError, ValueError):
            return _link(rel)
        if is_table(value):
            return table_html(value)
        if isinstance(value, dict) and isinstance(value.get("markdown"), str):
            return markdown_html(value["markdown"]) + _link(rel)
        return _link(rel)


def _flat_rows(value: Any, path: str = "") -> list[list[str]]:
    """A small JSON value as ``[field path, value]`` rows; a list of plain values stays on one row."""
    if isinstance(value, dict) and value:
        return [r for k, v in value.items() for r in _flat_rows(v, f"{path}.{k}" if path else str(k))]
    if isinstance(value, list) and value and not all(isinstance(v, (int, float, str, bool)) or v is None
                                                     for v in value):
        return [r for i, v in enumerate(value) for r in _flat_rows(v, f"{path}[{i}]")]
    return [[path or "value", json.dumps(value)]]


def _not_shown(rel: str) -> str:
    return f'<p class="err">not shown: {_e(rel)} is not a file of this run folder</p>'


def _href(rel: str) -> str:
    """A run-folder path as a relative URL: percent-encoded, so that an item's file name
    (``%2E%2E%2Fx.png``) is that file, and ``javascript:...`` is a file name, not a scheme."""
    return _e(urllib.parse.quote("/".join(_parts(rel)), safe="/"))


def _link(rel: str) -> str:
    return f'<div><a href="{_href(rel)}">{_e(rel)}</a></div>'


def is_table(v: Any) -> bool:
    """A saved *table* value: ``{"columns": [...], "rows": [[...], ...]}`` (``title`` optional)."""
    return (isinstance(v, dict) and isinstance(v.get("columns"), list) and isinstance(v.get("rows"), list)
            and all(isinstance(r, list) for r in v["rows"]))


def table_html(t: dict[str, Any], css_class: str = "sg-table") -> str:
    def cell(c: Any) -> str:
        if isinstance(c, float):
            return f"{c:.4g}"
        return "" if c is None else str(c)

    cap = f"<caption>{_e(t['title'])}</caption>" if t.get("title") else ""
    head = "".join(f"<th>{_e(c)}</th>" for c in t["columns"])
    body = "".join("<tr>" + "".join(f"<td>{_e(cell(c))}</td>" for c in r) + "</tr>" for r in t["rows"])
    return f'<table class="{css_class}">{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def markdown_html(md: str) -> str:
    """The little Markdown a node writes -- ``#`` headings, pipe tables, paragraphs -- as HTML (escaped);
    anything else in it stays text. A table read as monospace text is hard to scan."""
    out: list[str] = []
    lines = md.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        if line.startswith("|"):
            block = []
            while i < len(lines) and lines[i].strip().startswith("|"):
                block.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
                i += 1
            rows = [r for r in block if not all(re.fullmatch(r":?-{3,}:?", c) for c in r if c)]
            if rows:
                out.append(table_html({"columns": rows[0], "rows": rows[1:]}))
            continue
        heading = re.match(r"(#{1,6})\s+(.*)", line)
        if heading:
            level = min(6, len(heading.group(1)) + 2)  # under the page's own h1 / h2
            out.append(f"<h{level}>{_e(heading.group(2))}</h{level}>")
        elif line:
            out.append(f"<p>{_e(line)}</p>")
        i += 1
    return "".join(out)


def _parts(rel: str) -> list[str]:
    """``Path(rel).parts`` of a run-folder path, without making a Path (hundreds of files a page)."""
    return [p for p in re.split(r"[\\/]", rel) if p and p != "."]


def _group(files: list[str]) -> dict[str, list[str]]:
    """Files by output: ``node/out.png`` -> ``out``; ``node/out/item.png`` -> ``out``."""
    groups: dict[str, list[str]] = {}
    for f in files:
        parts = _parts(f)
        key = parts[1] if len(parts) > 2 else os.path.splitext(parts[-1])[0]
        groups.setdefault(key, []).append(f)
    return groups


def node_section(page: _Page, n: dict[str, Any]) -> str:
    name, status = n.get("node", "?"), n.get("status", "?")
    items = n.get("items") or 0
    bits = [f'<h2 id="node-{_e(name)}">{_e(name)} <small>({_e(n.get("type", ""))})</small> '
            f'<span class="st st-{_e(str(status).replace(" ", ""))}">{_e(status)}</span></h2>',
            f"<p>{float(n.get('seconds') or 0):.2f} s"
            + (f"; {_e(items)} items ({_e(n.get('items_ran', 0))} computed, {_e(n.get('items_failed', 0))} failed)"
               if items else "")
            + "</p>"]
    if n.get("error"):
        bits.append(f'<p class="err">{_e(n["error"])}</p>')
    if n.get("hint"):
        bits.append(f'<p class="hint">Fix: {_e(n["hint"])}</p>')
    messages = n.get("messages") or []
    for m in messages[:MESSAGES_SHOWN]:
        bits.append(f'<p class="hint">{_e(m)}</p>')
    if len(messages) > MESSAGES_SHOWN:  # say that the list goes on, and where
        bits.append(f'<p class="hint">&#8230; and {len(messages) - MESSAGES_SHOWN} more messages in '
                    f'<a href="run.json">run.json</a></p>')
    heads = n.get("headline") if isinstance(n.get("headline"), list) else []
    for out, files in _group([f for f in n.get("files", []) if isinstance(f, str)]).items():
        bits.append(f'<p><a href="#sg-result">{_e(out)}</a>: in the result above</p>' if out in heads
                    else output_block(page, out, files))
    return "\n".join(bits)


def output_block(page: _Page, out: str, files: list[str], title: str | None = None, small_json: bool = False) -> str:
    """One output's files: pictures (per-item ones folded: the first few, then a link to the folder),
    tables and Markdown rendered, the rest linked; ``small_json`` shows a short JSON value as text."""
    imgs = [f for f in files if os.path.splitext(f)[1].lower() in _MIME]
    rest = [f for f in files if f not in imgs]
    bits = [f'<div class="sg-output" data-output="{_e(out)}"><h3>{_e(title or out)}</h3>']
    per_item = len(_parts(imgs[0])) > 2 if imgs else False
    fold = per_item and len(imgs) > 1  # a picture per item: folded, so that the page stays short
    if fold:
        bits.append(f"<details><summary>{len(imgs)} pictures, one per item</summary>")
    bits += [page.image(f, f, "item" if per_item else "") for f in imgs[:IMAGES_PER_OUTPUT]]
    if len(imgs) > IMAGES_PER_OUTPUT:
        folder = Path(imgs[0]).parent.as_posix()
        bits.append(f'<p>&#8230; and {len(imgs) - IMAGES_PER_OUTPUT} more in '
                    f'<a href="{_href(folder)}">{_e(folder)}</a></p>')
    if fold:
        bits.append("</details>")
    for f in rest:
        bits.append(page.json_block(f, small_json) if f.endswith(".json") else
                    _link(f) if page.inside(f) else _not_shown(f))
    bits.append("</div>")
    return "\n".join(bits)


def result_section(page: _Page, nodes: list[dict[str, Any]]) -> str:
    """The answer first: what failed, the one-line summaries nodes gave (a calibration's RMS), and the
    outputs nodes declare as the run's headline (``Out(headline=True)``), in data-flow order."""
    bits = ['<section id="sg-result"><h2>result</h2>']
    for n in nodes:
        if n.get("error"):
            bits.append(f'<p class="err">{_e(n.get("node"))} ({_e(n.get("type"))}): {_e(n["error"])}</p>')
    said = [[n.get("node"), n["messages"][0]] for n in nodes
            if isinstance(n.get("messages"), list) and len(n["messages"]) == 1 and not n.get("error")]
    if said:
        bits.append(table_html({"title": "what the nodes said", "columns": ["node", "note"], "rows": said},
                               "sg-notes"))
    blocks = []  # pictures first, side by side with the tables: the answer fits a laptop's first screen
    for n in nodes:
        heads = n.get("headline") if isinstance(n.get("headline"), list) else []
        groups = _group([f for f in n.get("files", []) if isinstance(f, str)])
        for out in [o for o in heads if o in groups]:
            pictures = any(os.path.splitext(f)[1].lower() in _MIME for f in groups[out])
            blocks.append((not pictures, output_block(page, out, groups[out], f"{n.get('node')}: {out}", True)))
    if blocks:
        bits.append('<div class="sg-headline">' + "".join(b for _, b in sorted(blocks, key=lambda b: b[0]))
                    + "</div>")
    if len(bits) == 1:
        bits.append("<p>No node of this pipeline declares a headline output: see the nodes below.</p>")
    return "\n".join(bits) + "</section>"


def _contents(nodes: list[dict[str, Any]]) -> str:
    """Links to the nodes that saved pictures or tables (a long page: 120 overlays, a dozen nodes)."""
    links = [f'<li><a href="#node-{_e(n["node"])}">{_e(n["node"])}</a>: '
             + ", ".join(sorted({_e(k) for k in _group([f for f in n.get("files", []) if isinstance(f, str)])}))
             + "</li>" for n in nodes if n.get("files") and "node" in n]
    return f"<h3>outputs</h3><ul>{''.join(links)}</ul>" if links else ""


def flow_order(nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Nodes in data-flow order (each after the nodes it reads), otherwise as listed.

    run.json lists nodes as the pipeline file (and its includes) define them, so a node that an
    including file rewires can come before its inputs; the page reads top to bottom like the graph.
    """
    by_name = {n.get("node"): n for n in nodes}
    desc = {name: {"inputs": n.get("inputs") if isinstance(n.get("inputs"), dict) else {}}
            for name, n in by_name.items()}
    index = {name: i for i, name in enumerate(by_name)}
    order = nx.lexicographical_topological_sort(graph_picture.dag(desc), key=index.__getitem__)
    return [by_name[name] for name in order] + [n for n in nodes if by_name.get(n.get("node")) is not n]


def build_html(summary: dict[str, Any], run_dir: Path) -> str:
    page = _Page(run_dir)
    nodes = flow_order([n for n in summary.get("nodes", []) if isinstance(n, dict)])
    desc = {n["node"]: {"type": n.get("type", ""), "mapped": bool(n.get("mapped")), "inputs": n.get("inputs") or {}}
            for n in nodes if "node" in n}
    status = {n["node"]: n.get("status", "") for n in nodes if "node" in n}
    title = f"{Path(str(summary.get('pipeline', 'run'))).name} — run {summary.get('run_id', '')}"
    overview = {"title": "nodes", "columns": ["node", "type", "status", "seconds", "items", "error"],
                "rows": [[n.get("node"), n.get("type"), n.get("status"), round(float(n.get("seconds") or 0), 3),
                          n.get("items") or "", n.get("error") or ""] for n in nodes]}
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{_e(title)}</title>",
             f"<style>{_STYLE}</style></head><body>", f"<h1>{_e(title)}</h1>",
             f"<p>pipeline <code>{_e(summary.get('pipeline', ''))}</code>; result: "
             f"<b>{'ok' if summary.get('ok') else 'FAILED'}</b>"
             + (f"; overrides: <code>{_e(' '.join(summary.get('overrides') or []))}</code>" if summary.get("overrides")
                else "") + "</p>",
             '<p id="sg-images" data-ok="unknown">image check did not run</p>']
    for note in summary.get("notes") or []:
        parts.append(f'<p class="hint">note: {_e(note)}</p>')
    parts.append(result_section(page, nodes))
    if isinstance(summary.get("loop"), dict):
        from stereograph import report_cycles

        parts.append(report_cycles.cycles_section(page, summary["loop"], run_dir))
    svg = _ascii(graph_picture.to_svg(desc, status))
    parts.append(f'<h2 id="sg-details">graph and nodes</h2><div class="graph-row">'
                 f'<div class="graph" id="sg-graph">{svg}</div>'
                 f"<div>{table_html(overview, 'sg-overview')}{_contents(nodes)}</div></div>")
    for n in nodes:
        parts.append(f'<section class="sg-node-section" data-node="{_e(n.get("node", ""))}">'
                     f"{node_section(page, n)}</section>")
    parts.append(_CHECK + "</body></html>")
    return "\n".join(parts)


def write_html(path: Path, text: str) -> Path:
    """Write atomically: never a half-written page."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_report(run_dir: str | Path) -> Path:
    """(Re)build ``RUN_DIR/report.html`` from ``RUN_DIR/run.json``; returns its path.

    Raises :class:`~stereograph.errors.ConfigError` when the folder holds no readable ``run.json``.
    """
    from stereograph.errors import ConfigError

    d = Path(run_dir)
    try:
        summary = json.loads((d / "run.json").read_text())
        if not isinstance(summary, dict):
            raise ValueError("not a JSON object")
    except FileNotFoundError:
        raise ConfigError(f"{d} has no run.json: it is not the folder of a stereograph run",
                          hint="give the folder a run wrote (printed as 'outputs:' at the end of `stereograph run`)"
                          ) from None
    except (OSError, ValueError) as e:
        raise ConfigError(f"cannot read {d / 'run.json'}: {e}", hint="run the pipeline again to rewrite it") from None
    try:
        page = build_html(summary, d)
    except (TypeError, AttributeError, KeyError, ValueError) as e:  # a hand-edited or foreign run.json
        raise ConfigError(f"{d / 'run.json'} is not in the form stereograph writes ({type(e).__name__}: {e})",
                          hint="give the folder a run wrote, or run the pipeline again to rewrite it") from None
    return write_html(d / REPORT_NAME, page)
