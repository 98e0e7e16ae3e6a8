"""What ``stereograph run`` prints for a log, a pipe or a file, without importing rich.

A terminal gets rich's colours and layout; output that is not a terminal gets no colours from
rich either, only its layout -- which for the run's closing lines (the rules over the small
terminal outputs, their pretty-printed values and the summary table) is simple enough to produce
here, character for character as rich would (``tests/test_plaintext.py`` compares the two). That
spares a scripted rerun the import of rich and its layout engine (~0.1 s here, a fifth of a
replayed rerun's own time). Each function returns None for what it does not lay out exactly like
rich (text that is not printable ASCII, a table wider than the console, a console rich would
colour): the caller then prints with rich.
"""

from __future__ import annotations

import os
import re
from typing import Any

# Environment variables that make rich colour, or lay out as a terminal, output that is not one.
_RICH_FORCING = (
    "FORCE_COLOR",
    "TTY_COMPATIBLE",
    "TTY_INTERACTIVE",
    "JUPYTER_COLUMNS",
    "JUPYTER_LINES",
)


def plain_width(stream: Any, width: int) -> int | None:
    """``width`` when rich would print to ``stream`` without colours or terminal layout (not a
    terminal, nothing in the environment forcing one), else None."""
    try:
        if stream.isatty():
            return None
    except (AttributeError, ValueError):
        return None
    if any(os.environ.get(k) for k in _RICH_FORCING):
        return None
    return width


# rich replaces ":name:" with an emoji in console text (not in pretty-printed values)
_EMOJI_CODE = re.compile(r":\S*?:")


def _one_cell(c: str) -> bool:
    """A printable character that takes one terminal cell (as rich counts): ASCII, Latin, Greek,
    Cyrillic (up to U+052F, no combining marks) and the punctuation, arrows and maths signs of
    U+2010..U+22FF (combining marks for symbols left out) -- the test checks every one against
    rich's own cell widths."""
    o = ord(c)
    return c.isprintable() and (
        o < 0x300
        or 0x370 <= o < 0x483
        or 0x48A <= o < 0x530
        or 0x2010 <= o < 0x20D0
        or 0x2100 <= o < 0x2300
    )


def _plain(s: str, text: bool = True) -> bool:
    """Every character one cell wide (rich would lay it out as we count) and, for console
    ``text``, no emoji code."""
    if not (s.isascii() and s.isprintable()) and not all(map(_one_cell, s)):
        return False
    return not (text and ":" in s and _EMOJI_CODE.search(s))


def line(text: str) -> str | None:
    """``Console.print(text, markup=False)`` with soft wrap: the text as it is."""
    return text if _plain(text) else None


def rule(title: str, width: int) -> str | None:
    """``Console.rule(title, align="left")``: the title, a space, then a line to ``width``."""
    if not _plain(title) or len(title) > width - 2:  # (rich cuts a longer one with an ellipsis)
        return None
    return f"{title} " + "─" * (width - len(title) - 1)


def table(title: str, columns: list[str], rows: list[list[str]], width: int) -> str | None:
    """``rich.table.Table(*columns, title=title, title_justify="left")`` of ``rows`` (strings), as
    printed at ``width`` columns -- None when it would not fit (rich would wrap cells)."""
    cells = [columns, *rows]
    if not all(_plain(c) for r in cells for c in r) or not _plain(title):
        return None
    widths = [max(len(r[i]) for r in cells) for i in range(len(columns))]
    if sum(widths) + 3 * len(widths) + 1 > width or len(title) > width:
        return None

    def edge(left: str, fill: str, mid: str, right: str) -> str:
        return left + mid.join(fill * (w + 2) for w in widths) + right

    def row(r: list[str], bar: str) -> str:
        return bar + bar.join(f" {c.ljust(w)} " for c, w in zip(r, widths)) + bar

    out = [title, edge("┏", "━", "┳", "┓"), row(columns, "┃"), edge("┡", "━", "╇", "┩")]
    out += [row(r, "│") for r in rows]
    out.append(edge("└", "─", "┴", "┘"))
    return "\n".join(out)


# ----------------------------------------------------------------------------- pretty values


class _Node:
    """One value of the repr tree, as rich.pretty's Node for plain data (dicts, lists, scalars)."""

    __slots__ = ("key", "text", "open", "close", "children", "last")

    def __init__(
        self, text: str = "", open_: str = "", close: str = "", children: list | None = None
    ):
        self.key, self.text, self.open, self.close = "", text, open_, close
        self.children, self.last = children, False

    def tokens(self):
        if self.key:
            yield self.key
            yield ": "
        if self.text:
            yield self.text
        elif self.children:
            yield self.open
            for c in self.children:
                yield from c.tokens()
                if not c.last:
                    yield ", "
            yield self.close

    def fits(self, start: int, limit: int) -> bool:
        n = start
        for t in self.tokens():
            n += len(t)
            if n > limit:
                return False
        return True


def _tree(v: Any, max_string: int) -> _Node | None:
    if isinstance(v, dict):
        kids = []
        for k, x in v.items():
            node = _tree(x, max_string)
            key = _scalar(k, max_string)
            if node is None or key is None:
                return None
            node.key = key
            kids.append(node)
        if not kids:
            return _Node("{}")
        kids[-1].last = True
        return _Node("", "{", "}", kids)
    if isinstance(v, list):
        kids = []
        for x in v:
            node = _tree(x, max_string)
            if node is None:
                return None
            kids.append(node)
        if not kids:
            return _Node("[]")
        kids[-1].last = True
        return _Node("", "[", "]", kids)
    text = _scalar(v, max_string)
    return None if text is None else _Node(text)


def _scalar(v: Any, max_string: int) -> str | None:
    if isinstance(v, str):
        text = f"{v[:max_string]!r}+{len(v) - max_string}" if len(v) > max_string else repr(v)
    elif v is None or type(v) in (bool, int, float):
        text = repr(v)
    else:
        return None
    return text if _plain(text, text=False) else None


def pretty(value: Any, width: int, max_string: int = 200) -> str | None:
    """``rich.pretty.Pretty(value, indent_guides=False, max_string=max_string)`` printed at
    ``width`` columns, for JSON-like data: a container stays on one line while it fits, else
    its items go one per line, indented by 4. None for anything else."""
    root = _tree(value, max_string)
    if root is None:
        return None
    root.last = True
    # (indent, prefix text, node or None, suffix, last) per line, expanded in place as rich does
    lines: list[list[Any]] = [["", "", root, "", False, True]]
    i = 0
    while i < len(lines):
        ws, text, node, suffix, last, expandable = lines[i]
        if (
            expandable
            and node is not None
            and node.children
            and not node.fits(len(ws) + len(text) + len(suffix), width)
        ):
            head = f"{node.key}: {node.open}" if node.key else node.open
            new = [[ws, head, None, "", False, False]]
            inner = ws + "    "
            for c in node.children:
                # (", " counts 2 in the fit, as in rich)
                new.append([inner, "", c, ", ", c.last, True])
            new.append([ws, node.close, None, suffix, last, False])
            lines[i : i + 1] = new
        i += 1
    out = []
    for ws, text, node, suffix, last, _ in lines:
        body = ws + text + ("".join(node.tokens()) if node is not None else "")
        out.append(body if last else body + suffix.rstrip())
    return "\n".join(out)
