"""The pieces of a self-contained HTML page: escaping, tables, Markdown, embedded pictures.

Shared by ``report.html`` (:mod:`stereograph.app.report`, its cycles section) and ``compare.html``.
A page is ASCII, loads nothing from elsewhere, embeds pictures while a byte budget lasts and shows
only files inside its run folder (:meth:`Page.inside`). Public names: :class:`Page`, :func:`escape`,
:func:`table_html`, :func:`markdown_html`, :func:`is_table`, :func:`write_html`, :data:`STYLE`,
:data:`CHECK`.
"""

from __future__ import annotations

import base64
import html
import json
import os
import re
import urllib.parse
from pathlib import Path
from typing import Any

from stereograph.core.outputs import write_whole

# beyond this, images are linked (they lie beside the page) instead of embedded
EMBED_BUDGET_BYTES = 48 * 2**20
MAX_JSON_BYTES = 2 * 2**20
SMALL_JSON_BYTES = 4096  # a headline JSON value up to this size is shown as text (a pick's summary)
FIELDS_SHOWN = 10  # ... its first fields
MIME = {".png": "image/png", ".svg": "image/svg+xml", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}

STYLE = """
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
figure img{max-width:720px;border:1px solid #ddd}figure.item img{max-width:640px}
figure.wide img{max-width:100%}
.graph-row{display:flex;gap:2em;align-items:flex-start;flex-wrap:wrap}.err{color:#a00}.hint{color:#555}
pre{background:#f7f7f7;padding:.5em;overflow-x:auto;font-size:.85em}.graph{overflow-x:auto}
.sg-headline{display:flex;flex-wrap:wrap;gap:0 1.5em;align-items:flex-start}
.sg-headline h3{margin:.3em 0;font-size:1em}.sg-headline figure img{max-width:600px}
#sg-result h2{margin-top:.6em}
"""

CHECK = """
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


def escape(x: Any) -> str:
    return ascii_only(html.escape(str(x)))


def ascii_only(text: str) -> str:
    """Non-ASCII characters as character references: the page is ASCII, so joining and writing its
    megabytes of embedded pictures stays a byte copy (a single "—" would make Python store and
    encode the whole page at two bytes a character)."""
    return text if text.isascii() else text.encode("ascii", "xmlcharrefreplace").decode("ascii")


class Page:
    def __init__(self, run_dir: Path):
        self.dir = run_dir
        self.budget = EMBED_BUDGET_BYTES
        self._root: str | None = None

    def inside(self, rel: str) -> bool:
        """Whether ``rel`` names a file in the run folder. run.json may come from someone else (a
        run folder handed over, then ``stereograph report``): a path that is absolute, climbs out
        with ``..`` or passes through a symbolic link (stereograph makes none) must not put a file
        from elsewhere on the page -- embedded, it would go wherever the page goes."""
        if (
            not isinstance(rel, str)
            or not rel
            or os.path.isabs(rel)
            or ".." in path_parts(rel)
            or "\0" in rel
        ):
            return False
        if self._root is None:
            self._root = os.path.realpath(self.dir)
        return os.path.realpath(os.path.join(self.dir, rel)) == os.path.join(
            self._root, *path_parts(rel)
        )

    def image(self, rel: str, caption: str, css_class: str = "") -> str:
        """One figure: embedded while the budget lasts, else linked (the file lies beside the
        page)."""
        p = self.dir / rel
        mime = MIME.get(p.suffix.lower())
        if not self.inside(rel):
            return not_shown(rel)
        try:
            size = p.stat().st_size
        except OSError:
            return f'<p class="err">missing file {escape(rel)}</p>'
        if size <= self.budget:
            self.budget -= size
            src = f"data:{mime};base64," + base64.b64encode(p.read_bytes()).decode("ascii")
        else:
            src = href(rel)
        return (
            f'<figure class="{css_class}"><img src="{src}" alt="{escape(rel)}" '
            f'data-file="{escape(rel)}" '
            'loading="eager">'
            f"<figcaption>{escape(caption)}</figcaption></figure>"
        )

    def json_block(self, rel: str, small_as_text: bool = False) -> str:
        p = self.dir / rel
        if not self.inside(rel):
            return not_shown(rel)
        try:
            size = p.stat().st_size
            if size > MAX_JSON_BYTES:
                return link(rel)
            data = p.read_bytes()
            if (
                small_as_text
                and size <= SMALL_JSON_BYTES
                and not (b'"columns"' in data or b'"markdown"' in data)
            ):
                rows = flat_rows(json.loads(data))
                more = (
                    f"<p>&#8230; {len(rows) - FIELDS_SHOWN} more fields in</p>"
                    if len(rows) > FIELDS_SHOWN
                    else ""
                )
                return (
                    table_html(
                        {"columns": ["field", "value"], "rows": rows[:FIELDS_SHOWN]}, "sg-fields"
                    )
                    + more
                    + link(rel)
                )
            # Only a table or a markdown value is shown: a file without their keys is linked
            # unparsed (json.dumps writes a key's ASCII letters as they are; a run's records are
            # most of its JSON).
            if not ((b'"columns"' in data and b'"rows"' in data) or b'"markdown"' in data):
                return link(rel)
            value = json.loads(data)
        except (OSError, ValueError):
            return link(rel)
        if is_table(value):
            return table_html(value)
        if isinstance(value, dict) and isinstance(value.get("markdown"), str):
            return markdown_html(value["markdown"]) + link(rel)
        return link(rel)


def flat_rows(value: Any, path: str = "") -> list[list[str]]:
    """A small JSON value as ``[field path, value]`` rows; a list of plain values stays on one
    row."""
    if isinstance(value, dict) and value:
        return [
            r for k, v in value.items() for r in flat_rows(v, f"{path}.{k}" if path else str(k))
        ]
    if (
        isinstance(value, list)
        and value
        and not all(isinstance(v, (int, float, str, bool)) or v is None for v in value)
    ):
        return [r for i, v in enumerate(value) for r in flat_rows(v, f"{path}[{i}]")]
    return [[path or "value", json.dumps(value)]]


def not_shown(rel: str) -> str:
    return f'<p class="err">not shown: {escape(rel)} is not a file of this run folder</p>'


def href(rel: str) -> str:
    """A run-folder path as a relative URL: percent-encoded, so that an item's file name
    (``%2E%2E%2Fx.png``) is that file, and ``javascript:...`` is a file name, not a scheme."""
    return escape(urllib.parse.quote("/".join(path_parts(rel)), safe="/"))


def link(rel: str) -> str:
    return f'<div><a href="{href(rel)}">{escape(rel)}</a></div>'


def is_table(v: Any) -> bool:
    """A saved *table* value: ``{"columns": [...], "rows": [[...], ...]}`` (``title`` optional)."""
    return (
        isinstance(v, dict)
        and isinstance(v.get("columns"), list)
        and isinstance(v.get("rows"), list)
        and all(isinstance(r, list) for r in v["rows"])
    )


def table_html(t: dict[str, Any], css_class: str = "sg-table") -> str:
    def cell(c: Any) -> str:
        if isinstance(c, float):
            return f"{c:.4g}"
        return "" if c is None else str(c)

    cap = f"<caption>{escape(t['title'])}</caption>" if t.get("title") else ""
    head = "".join(f"<th>{escape(c)}</th>" for c in t["columns"])
    body = "".join(
        "<tr>" + "".join(f"<td>{escape(cell(c))}</td>" for c in r) + "</tr>" for r in t["rows"]
    )
    return (
        f'<table class="{css_class}">{cap}<thead><tr>{head}</tr></thead>'
        f"<tbody>{body}</tbody></table>"
    )


def markdown_html(md: str) -> str:
    """The little Markdown a node writes -- ``#`` headings, pipe tables, paragraphs -- as HTML
    (escaped); anything else in it stays text. A table read as monospace text is hard to scan."""
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
            out.append(f"<h{level}>{escape(heading.group(2))}</h{level}>")
        elif line:
            out.append(f"<p>{escape(line)}</p>")
        i += 1
    return "".join(out)


def path_parts(rel: str) -> list[str]:
    """``Path(rel).parts`` of a run-folder path, without making a Path (hundreds of files a
    page)."""
    return [p for p in re.split(r"[\\/]", rel) if p and p != "."]


def write_html(path: Path, text: str) -> Path:
    """Write atomically: never a half-written page."""
    write_whole(path, text.encode("utf-8"))
    return path
