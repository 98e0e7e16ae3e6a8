"""What a run gives back: each node's :class:`NodeReport`, the whole run's :class:`RunResult`, and
what a part of a run (a streamed chunk) hands the run (:class:`PartRecords`).

Plain data shapes; :mod:`stereograph.core.run_state` fills them. ``Ref`` is ``(node, output,
item)``; a value kept in memory only has a :func:`memory_key`, one made again at every run a
:func:`volatile_key`; :func:`is_lasting_key` tells them from a key a later run finds again.
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

Ref = tuple[str, str, "str | None"]  # (node, output, item)
NO_ITEMS = "no items to process (upstream produced none)"  # a per-item node's message


def memory_key(*parts: Any) -> str:
    """The key of a value held in memory only (no store, or a loop's live part): ``node/...``.
    A store's keys are hex digests, never with a ``/`` (:func:`is_memory_key`)."""
    return "/".join(str(p) for p in parts)


def is_memory_key(key: str) -> bool:
    """True for a :func:`memory_key`: no store holds its value."""
    return "/" in key


def volatile_key() -> str:
    """A fresh key for a value made again at every run (a camera's grab, an arm's move): stored,
    but never found again, so nothing downstream is served a stale value."""
    return f"volatile-{uuid.uuid4().hex}"


def is_lasting_key(key: str) -> bool:
    """True for a key a later run can find again: neither a memory nor a volatile key."""
    return not is_memory_key(key) and not key.startswith("volatile-")


@dataclass
class NodeReport:
    name: str
    type: str
    status: str = "pending"  # ran | cached | failed | skipped | partial
    seconds: float = 0.0
    items: int = 0
    items_ran: int = 0
    items_failed: int = 0
    error: str | None = None
    hint: str | None = None
    trace: str | None = None
    unexpected: bool = False  # a bug in the node rather than bad input
    messages: list[str] = field(default_factory=list)
    # its failure would come back on every later call (NodeError(lasting=True))
    lasting: bool = False


@dataclass
class RunResult:
    run_id: str
    pipeline: str
    out_dir: Path
    reports: dict[str, NodeReport]
    seconds: float
    values: Mapping[Ref, Any]  # the terminal, saved and kept outputs' values
    item_ids: dict[tuple[str, str], list[str]]  # their collections' items
    item_errors: dict[tuple[str, str], str] = field(default_factory=dict)
    terminal: list[str] = field(default_factory=list)
    # about the run as a whole (a read-only cache, say)
    notes: list[str] = field(default_factory=list)
    # the finished run: loads any node's output from the cache
    state: Any = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        return not any(r.status in ("failed", "partial") for r in self.reports.values())

    @property
    def status(self) -> dict[str, str]:
        return {n: r.status for n, r in self.reports.items()}

    @property
    def ran(self) -> set[str]:
        return {n for n, r in self.reports.items() if r.status in ("ran", "partial") or r.items_ran}

    def holds(self, node: str, output: str) -> bool:
        """Whether the result holds this output (terminal, saved or kept)."""
        return (node, output) in self.item_ids or (node, output, None) in self.values

    def outputs(self, node: str, output: str) -> Any:
        """A terminal (or saved) output: the value, or ``{item: value}`` for per-item outputs."""
        if (node, output) in self.item_ids:
            return {
                i: self.values[(node, output, i)]
                for i in self.item_ids[(node, output)]
                if (node, output, i) in self.values
            }
        return self.values.get((node, output, None))


@dataclass
class PartRecords:
    """What a part of a run (a streamed chunk of items) made, for the run to take in: its nodes'
    reports, item lists, failed items, entry and content keys, and the values it sends back."""

    reports: dict[str, NodeReport]
    items: dict[tuple[str, str], list[str]]
    failed: dict[tuple[str, str | None], str]
    ref_keys: dict[Ref, str]
    ref_ids: dict[Ref, str]
    keys: dict[tuple[str, str | None], str]
    values: dict[Ref, Any] = field(default_factory=dict)
    files: dict[tuple[str, str], dict[str, list[str]]] = field(default_factory=dict)
    # about nodes outside the part (a corrupt entry read)
    messages: dict[str, list[str]] = field(default_factory=dict)
