"""User-facing errors: one paragraph naming file, line, node and the fix."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Where:
    """A place in a pipeline file (1-based line and column)."""

    file: str
    line: int | None = None
    column: int | None = None

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

    def __init__(self, message: str, where: Where | None = None, node: str | None = None,
                 hint: str | None = None):
        super().__init__(message)
        self.message, self.where, self.node, self.hint = message, where, node, hint

    def __str__(self) -> str:
        parts = []
        if self.where is not None:
            parts.append(f"{self.where}:")
        if self.node:
            parts.append(f"node '{self.node}':")
        parts.append(self.message.rstrip())
        text = sentence(" ".join(parts))
        if self.hint:
            text += " Fix: " + sentence(self.hint)
        return text


def sentence(text: str) -> str:
    """End with exactly one full stop (a question keeps its '?')."""
    text = text.rstrip()
    return text if text.endswith((".", "?", "!")) else text + "."


class UsageError(ConfigError):
    """A bad command line (exit code 2)."""
