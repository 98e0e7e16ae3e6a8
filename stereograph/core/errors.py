"""User-facing errors: one paragraph naming file, line, node and the fix."""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from typing import Any


@dataclass
class Where:
    """A place in a pipeline file (1-based line and column); ``included_at``: where the file was
    read through ``include:``, the innermost ``include:`` line first."""

    file: str
    line: int | None = None
    column: int | None = None
    included_at: tuple[Where, ...] = ()

    def __str__(self) -> str:
        if self.line is None:
            return self.file
        return f"{self.file}:{self.line}" + (f":{self.column}" if self.column else "")


class ConfigError(Exception):
    """A pipeline that cannot run as written (exit code 2).

    Parameters
    ----------
    message : str
        What is wrong.
    where : Where, optional
        The file and line it comes from.
    node : str, optional
        The node instance concerned.
    hint : str, optional
        How to fix it.
    """

    exit_code = 2

    def __init__(
        self,
        message: str,
        where: Where | None = None,
        node: str | None = None,
        hint: str | None = None,
    ):
        super().__init__(message)
        self.message, self.where, self.node, self.hint = message, where, node, hint

    def __str__(self) -> str:
        parts = []
        if self.where is not None:
            parts.append(f"{self.where}:")
        if self.node:
            parts.append(f"node '{self.node}':")
        parts.append(self.message.rstrip())
        if self.where is not None and self.where.included_at:
            parts[-1] = parts[-1].rstrip(" .")
            chain = (f"in a file included at {at}" for at in self.where.included_at)
            parts.append("(" + ", ".join(chain) + ")")
        text = sentence(" ".join(parts))
        if self.hint:
            text += " Fix: " + sentence(self.hint)
        return text


def did_you_mean(word: str, options: Any, listing: str, prefix: str = "") -> str:
    """A Fix for a misspelt name: the closest of ``options``, else ``listing`` and all of them."""
    close = difflib.get_close_matches(word, list(options), n=1)
    return (
        f"did you mean '{prefix}{close[0]}'?" if close else f"{listing} {sorted(options) or 'none'}"
    )


def sentence(text: str) -> str:
    """End with exactly one full stop (a question keeps its '?')."""
    text = text.rstrip()
    return text if text.endswith((".", "?", "!")) else text + "."


class UsageError(ConfigError):
    """A bad command line (exit code 2)."""


class ConfigErrors(ConfigError):
    """Several problems of one pipeline, found in one pass (``validate`` lists them all).

    Its ``message``, ``where``, ``node`` and ``hint`` are the first problem's, so code that reads
    one :class:`ConfigError` keeps working; ``errors`` holds every one, in file order.

    Parameters
    ----------
    errors : list of ConfigError
        Two or more problems.
    doc : PipelineDoc, optional
        The pipeline as far as it could be read (nodes with a problem of their own left out),
        so that later checks can still look at the rest.
    """

    def __init__(self, errors: list[ConfigError], doc: object | None = None):
        first = errors[0]
        super().__init__(first.message, first.where, first.node, first.hint)
        self.errors, self.doc = list(errors), doc
        self.exit_code = max(e.exit_code for e in errors)

    def __str__(self) -> str:
        return "\n".join(str(e) for e in self.errors)


def raise_all(errors: list[ConfigError], doc: object | None = None) -> None:
    """Raise nothing, the one error, or a :class:`ConfigErrors` of all of them (sorted by file and
    line)."""
    if not errors:
        return
    flat = in_file_order(errors)
    if len(flat) == 1 and doc is None:
        raise flat[0]
    raise ConfigErrors(flat, doc)


def in_file_order(errors: list[ConfigError]) -> list[ConfigError]:
    """Errors sorted by file and line (unlocated ones last), each :class:`ConfigErrors` unpacked."""
    flat: list[ConfigError] = []
    for e in errors:
        flat += e.errors if isinstance(e, ConfigErrors) else [e]
    return sorted(
        flat,
        key=lambda e: (
            e.where is None,
            e.where.file if e.where else "",
            (e.where.line or 0) if e.where else 0,
        ),
    )


# Control characters (ESC, CR, BEL, ...) and the bidirectional overrides. User text -- a value in a
# pipeline file ("\\e[2J" is valid YAML), an image's file name, a node's message -- reaches the
# terminal in errors and tables; these would let it clear the screen, move the cursor over a
# warning, retitle the window or reorder what is shown.
_UNPRINTABLE = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")


def printable(text: str) -> str:
    """``text`` with its control characters written as escapes (``\\x1b``), newlines and tabs
    kept."""
    return _UNPRINTABLE.sub(lambda m: ascii(m.group())[1:-1], text)
