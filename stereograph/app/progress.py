"""Progress of a run: a live bar per node on a terminal, plain lines everywhere else.

The runner calls ``node_started(name, n_items)``, ``advance(name)`` and, when they exist,
``item_failed(name)`` and ``item_progress(name, done, total, unit)`` (a node's own report through
``ctx.progress``). :class:`PlainProgress` (logs, CI, pipes, notebooks: a line per running node
every few seconds, from a heartbeat thread) and :class:`RichProgress` (bars with an ETA).
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass
from typing import IO, Any

__all__ = ["Mutable", "PlainProgress", "RichProgress", "eta_seconds"]


def eta_seconds(done: float, total: float, elapsed_s: float) -> float | None:
    """Seconds left at the mean rate so far (None before the first unit is done or past the end)."""
    if done <= 0 or total <= 0 or done >= total:
        return None
    return elapsed_s / done * (total - done)


def _duration(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    if seconds < 60:
        return f"{seconds} s"
    m, s = divmod(seconds, 60)
    return f"{m} min {s:02d} s" if m < 60 else f"{m // 60} h {m % 60:02d} min"


@dataclass
class _NodeState:
    items: int
    started: float
    entries_done: int = 0
    done: float = 0  # the node's own count (item_progress), within the current call
    total: float = 0
    unit: str = ""
    # when this unit's count began (a node may report phases: scenes, then views)
    unit_started: float = 0.0
    failed: int = 0  # entries that failed

    def line(self, name: str, now: float) -> str:
        parts = [name]
        if self.items > 1:
            parts.append(f"{self.entries_done}/{self.items} items")
        if self.total:
            parts.append(f"{self.done:g}/{self.total:g} {self.unit}".rstrip())
            eta = eta_seconds(self.done, self.total, now - self.unit_started)
        else:
            eta = (
                eta_seconds(self.entries_done, self.items, now - self.started)
                if self.items > 1
                else None
            )
        text = " ".join(parts[:1]) + (" " + ", ".join(parts[1:]) if len(parts) > 1 else "")
        text += f", {_duration(now - self.started)} elapsed"
        if eta is not None:
            text += f", ETA {_duration(eta)}"
        return text


class PlainProgress:
    """One plain line per running node every few seconds (logs, pipes, CI, notebooks).

    Parameters
    ----------
    stream : file, optional
        Where to write (default ``sys.stdout``).
    interval_s : float
        Seconds between two lines about the same running node.
    """

    def __init__(self, stream: IO[str] | None = None, interval_s: float = 5.0):
        self.stream = stream if stream is not None else sys.stdout
        self.interval_s = float(interval_s)
        self.nodes: dict[str, _NodeState] = {}
        self._last_line: dict[str, float] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---- lifetime: a heartbeat thread while the run lasts

    def __enter__(self) -> PlainProgress:
        self._stop.clear()
        self._thread = threading.Thread(target=self._beat, name="stereograph-progress", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> bool:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2 * self.interval_s)
        stopped = exc[0] is not None and issubclass(exc[0], (KeyboardInterrupt, SystemExit))
        with self._lock:
            for name in list(self.nodes):
                self._finish(name, "interrupted" if stopped else None)
        return False

    def _beat(self) -> None:
        tick = min(1.0, self.interval_s / 2)
        while not self._stop.wait(tick):
            now = time.monotonic()
            with self._lock:
                for name, st in self.nodes.items():
                    if now - self._last_line.get(name, st.started) >= self.interval_s:
                        self._print(st.line(name, now))
                        self._last_line[name] = now

    def _print(self, text: str) -> None:
        try:
            print(text, file=self.stream, flush=True)
        except (OSError, ValueError):  # a closed pipe must not fail the run
            pass

    # ---- the runner's calls

    def node_started(self, name: str, n_items: int) -> None:
        with self._lock:
            # the serial runner starts a node once the previous one ended
            for other in list(self.nodes):
                self._finish(other)
            now = time.monotonic()
            self.nodes[name] = _NodeState(items=n_items, started=now, unit_started=now)
            self._last_line[name] = now
            self._print(f"{name}: started" + (f" ({n_items} items)" if n_items > 1 else ""))

    def advance(self, name: str) -> None:
        with self._lock:
            st = self.nodes.get(name)
            if st is None:
                return
            st.entries_done += 1
            st.done = st.total = 0  # the next call reports its own count
            if st.entries_done >= st.items:
                self._finish(name)
            else:
                self._maybe_print(name, st)

    def item_failed(self, name: str) -> None:
        with self._lock:
            st = self.nodes.get(name)
            if st is not None:
                st.failed += 1

    def item_progress(self, name: str, done: float, total: float, unit: str = "items") -> None:
        with self._lock:
            st = self.nodes.get(name)
            if st is None:
                return
            now = time.monotonic()
            if unit != st.unit or done < st.done:
                st.unit_started = now
            st.done, st.total, st.unit = done, total, unit
            self._maybe_print(name, st)

    def _maybe_print(self, name: str, st: _NodeState) -> None:
        now = time.monotonic()
        if now - self._last_line.get(name, st.started) >= self.interval_s:
            self._print(st.line(name, now))
            self._last_line[name] = now

    def _finish(self, name: str, how: str | None = None) -> None:
        st = self.nodes.pop(name, None)
        self._last_line.pop(name, None)
        if st is None:
            return
        items = f"{st.entries_done}/{st.items} items, " if st.items > 1 else ""
        if st.failed and st.items > 1:
            items += f"{st.failed} failed, "
        if how is None:
            how = "failed" if st.failed and st.failed >= st.entries_done else "finished"
        self._print(f"{name}: {how} ({items}{_duration(time.monotonic() - st.started)})")


class RichProgress:
    """Progress bars for a terminal: one per node, with the node's own count and an ETA."""

    def __init__(self, console: Any):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.p = Progress(
            TextColumn("{task.description:<24}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[unit]}"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=console,
            transient=True,
        )
        self.tasks: dict[str, Any] = {}
        self.items: dict[str, int] = {}

    def __enter__(self) -> RichProgress:
        self.p.__enter__()
        return self

    def __exit__(self, *a: Any) -> None:
        self.p.__exit__(*a)

    def node_started(self, name: str, n_items: int) -> None:
        self.items[name] = max(n_items, 1)
        self.tasks[name] = self.p.add_task(
            name, total=self.items[name], unit="items" if n_items > 1 else ""
        )

    def advance(self, name: str) -> None:
        task = self.tasks.get(name)
        if task is None:
            return
        t = self.p.tasks[[x.id for x in self.p.tasks].index(task)]
        if t.fields.get("own"):  # the bar showed the node's own count: back to its entries
            self.p.reset(
                task,
                total=self.items[name],
                completed=t.fields.get("entries", 0),
                unit="items" if self.items[name] > 1 else "",
                own=False,
            )
        entries = t.fields.get("entries", 0) + 1
        self.p.update(task, completed=entries, entries=entries)

    def item_progress(self, name: str, done: float, total: float, unit: str = "items") -> None:
        task = self.tasks.get(name)
        if task is None:
            return
        t = self.p.tasks[[x.id for x in self.p.tasks].index(task)]
        if not t.fields.get("own") or t.fields.get("unit") != unit or done < t.completed:
            # a new count (or a new phase: scenes, then views): restart so the ETA uses this count's
            # rate
            self.p.reset(
                task,
                total=total,
                completed=done,
                unit=unit,
                own=True,
                entries=t.fields.get("entries", 0),
            )
        else:
            self.p.update(task, total=total, completed=done)


class Mutable:
    """A progress display that can be switched off part-way: a ``--repeat`` loop's later cycles,
    whose one line per cycle says it all (``--verbose`` keeps the per-node lines)."""

    def __init__(self, inner: Any):
        self.inner = inner
        self.muted = False

    def mute(self) -> None:
        self.muted = True

    def __enter__(self) -> Mutable:
        self.inner.__enter__()
        return self

    def __exit__(self, *exc: Any) -> Any:
        return self.inner.__exit__(*exc)

    def __getattr__(self, name: str) -> Any:
        call = getattr(self.inner, name)
        return (lambda *a, **k: None) if self.muted else call
