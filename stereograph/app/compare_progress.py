"""A comparison's progress: :class:`CompareLines` (a line per variant, and the running node's lines,
for logs and pipes) and :class:`CompareBars` (rich bars over the variants and the running node).

Both take the scheduler's progress calls (``node_started``, ``advance``, ...) and the comparison's
own (``variant_started``, ``variant_skipped``, ``variant_done``).
"""

from __future__ import annotations

from stereograph.app.compare_result import VariantResult
from stereograph.app.progress import PlainProgress
from stereograph.core.errors import printable


class CompareLines:
    """Progress lines for a non-terminal: one per variant, and the run's per-node lines
    (:class:`stereograph.app.progress.PlainProgress`: a line per running node every few seconds)."""

    def __init__(self, stream=None, interval_s: float = 5.0):
        self.stream = stream
        self.nodes = PlainProgress(stream, interval_s) if stream else None

    def __enter__(self):
        if self.nodes is not None:
            self.nodes.__enter__()
        return self

    def __exit__(self, *a):
        if self.nodes is not None:
            self.nodes.__exit__(*a)
        return False

    def variant_started(self, i: int, n: int, label: str) -> None:
        if self.stream:
            print(printable(f"[{i}/{n}] {label} ..."), file=self.stream, flush=True)

    def variant_skipped(self, label: str, why: str) -> None:
        if self.stream:
            print(
                printable(f"left out (its settings do not validate): {label}: {why}"),
                file=self.stream,
                flush=True,
            )

    def variant_done(self, vr: VariantResult) -> None:
        if self.stream:
            ran = vr.computed
            state = "ok" if vr.ok else f"FAILED: {vr.error}"
            print(
                printable(f"      {state}; computed: {ran} ({vr.seconds:.1f} s)"),
                file=self.stream,
                flush=True,
            )

    def node_started(self, name: str, n_items: int) -> None:
        if self.nodes is not None:
            self.nodes.node_started(name, n_items)

    def advance(self, name: str) -> None:
        if self.nodes is not None:
            self.nodes.advance(name)

    def item_failed(self, name: str) -> None:
        if self.nodes is not None:
            self.nodes.item_failed(name)

    def item_progress(self, name: str, done: float, total: float, unit: str = "items") -> None:
        if self.nodes is not None:
            self.nodes.item_progress(name, done, total, unit)


class CompareBars(CompareLines):
    """A bar over the variants and one for the node running now."""

    def __init__(self, console):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        super().__init__(None)
        self.console = console
        self.p = Progress(
            TextColumn("{task.description:<48}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
            transient=True,
        )
        self.overall = None
        self.current = None

    def __enter__(self):
        self.p.__enter__()
        return self

    def __exit__(self, *a):
        self.p.__exit__(*a)
        return False

    def variant_started(self, i: int, n: int, label: str) -> None:
        if self.overall is None:
            self.overall = self.p.add_task("variants", total=n)
        from rich.markup import escape

        self.p.update(self.overall, description=escape(printable(f"variant {i}/{n}: {label}"[:48])))

    def variant_done(self, vr: VariantResult) -> None:
        self.p.advance(self.overall)
        ran = vr.computed
        from rich.markup import escape  # labels and errors are user text: print them literally

        mark = "[green]ok[/]" if vr.ok else f"[red]failed[/]: {escape(str(vr.error))}"
        self.console.print(
            f"{escape(vr.variant.label)}: {mark}; computed {escape(ran)} ({vr.seconds:.1f} s)"
        )

    def node_started(self, name: str, n_items: int) -> None:
        if self.current is not None:
            self.p.remove_task(self.current)
        self.n_items, self.entries = max(n_items, 1), 0
        self.current = self.p.add_task(f"  {name}", total=self.n_items)

    def advance(self, name: str) -> None:
        if self.current is not None:
            self.entries += 1  # (back from the node's own count, if it showed one)
            self.p.update(self.current, total=self.n_items, completed=self.entries)

    def item_progress(self, name: str, done: float, total: float, unit: str = "items") -> None:
        if self.current is not None:  # the node's own count inside one call (a source's scenes)
            self.p.update(
                self.current, total=total, completed=done, description=f"  {name} ({unit})"
            )
