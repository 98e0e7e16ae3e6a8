"""What the core announces, for the commands and pages on top of it to act on.

The core never imports :mod:`stereograph.app`. Where it must notify -- a run folder written (the
app builds its page), cache entries pruned (the app drops what links to them) -- it announces the
event here and calls what was registered. A callback's failure is returned, never raised: the
run's results are already written. Public names: :data:`EVENTS`, :func:`register`, :func:`announce`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

# : ``run_written(out_dir)``: ``run.json`` is in place; ``cache_pruned(cache_root)``: entries were
# deleted.
EVENTS = ("run_written", "cache_pruned")
_CALLBACKS: dict[str, dict[str, Callable[..., Any]]] = {event: {} for event in EVENTS}


def register(event: str, what: str, callback: Callable[..., Any]) -> None:
    """Call ``callback`` on ``event``; ``what`` names the work in a failure's note (one per
    name)."""
    if event not in _CALLBACKS:
        raise ValueError(f"unknown event {event!r}; the core announces {', '.join(EVENTS)}")
    _CALLBACKS[event][what] = callback


def announce(event: str, *args: Any) -> list[str]:
    """Call every callback of ``event``; returns a note per callback that failed."""
    notes = []
    for what, callback in list(_CALLBACKS[event].items()):
        try:
            callback(*args)
        except Exception as e:  # the core's work is done: a page that cannot be built is a note
            notes.append(f"{what} not written: {type(e).__name__}: {e}")
    return notes
