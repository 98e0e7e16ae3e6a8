"""The commands and pages on top of :mod:`stereograph.core`: cli, compare, explain, loop, rerun,
report pages, progress display and the Python facade (``pyapi``).

Importing the package registers what the app does on the core's announcements
(:mod:`stereograph.core.hooks`): a written run folder gets its ``report.html``; a pruned cache
drops the replay memos that link to its files.
"""

from pathlib import Path

from stereograph.core import hooks


def write_report(out_dir: Path) -> None:
    """``report.html`` for a run folder (imported on use: a run that writes no page pays
    nothing)."""
    from stereograph.app import report

    report.write_report(out_dir)


def forget_replays(cache_root: Path) -> None:
    """Drop the replay memos of a cache (their hard links must not keep pruned files on disk)."""
    from stereograph.app import rerun

    rerun.forget(cache_root)


hooks.register("run_written", "report.html", write_report)
hooks.register("cache_pruned", "replay memos", forget_replays)
