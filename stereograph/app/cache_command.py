"""``stereograph cache info | prune --max-gb N | clear``: a project's cache, looked at or emptied
once no run uses it.

Public: :func:`cmd_cache`, :func:`cache_positionals_first`, :data:`CACHE_WAIT_S`.
"""

from __future__ import annotations

from pathlib import Path

from stereograph.app.console import command_console
from stereograph.core.errors import ConfigError

CACHE_WAIT_S = 30.0  # cache prune / clear wait this long for running runs to end


def _cache_remove(args, store, root: Path, con) -> int:
    """``cache clear`` / ``cache prune``: once no run uses the cache (CacheBusy after
    CACHE_WAIT_S)."""
    if args.action == "clear":
        n = store.clear(wait_s=CACHE_WAIT_S)
        con.print(f"removed {_entries(n)} from {root}", markup=False)
        return 0
    if args.max_gb is None:
        raise ConfigError(
            "cache prune needs --max-gb", hint="for example: stereograph cache prune --max-gb 5"
        )
    left = store.sweep_abandoned() if store.writable else 0  # (prune would, first: said apart here)
    n, freed = store.prune(int(args.max_gb * 1e9), wait_s=CACHE_WAIT_S)
    con.print(
        f"removed {_entries(n, 'least recently used ')} ({freed / 1e6:.1f} MB) from {root}",
        markup=False,
    )
    if left:
        con.print(
            f"removed {left / 1e6:.1f} MB of unfinished entries killed runs had left in "
            f"{store.tmp}",
            markup=False,
        )
    return 0


def cmd_cache(args) -> int:
    from stereograph.core.cache import ArtifactStore
    from stereograph.core.config import load_pipeline
    from stereograph.core.project import cache_dir

    if args.cache_dir:
        root = Path(args.cache_dir)
    else:
        root = cache_dir(load_pipeline(args.pipeline).directory if args.pipeline else Path.cwd())
    store = ArtifactStore(root)
    con = command_console()
    if args.action in ("clear", "prune"):
        from stereograph.core.cache import CacheBusy

        try:
            return _cache_remove(args, store, root, con)
        except CacheBusy:
            command_console(stderr=True).print(
                f"error: a run is using the cache {root} (still after {CACHE_WAIT_S:g} "
                "s): nothing was removed, so "
                "that no entry disappears under it. Fix: run `stereograph cache "
                f"{args.action}` again when it has "
                "ended (a --repeat loop holds the cache until it stops).",
                markup=False,
            )
            return 1
    from stereograph.core.project import budget_bytes

    budget = budget_bytes(Path(args.pipeline).parent if args.pipeline else Path.cwd())
    info = store.info(budget)
    limit = (
        f" of a {budget / 1e9:g} GB budget (least recently used entries pruned after runs)"
        if budget
        else " (no budget)"
    )
    con.print(
        f"cache {info['root']}: {_entries(info['entries'])}, {info['bytes'] / 1e6:.1f} MB{limit}",
        markup=False,
    )
    for t, (n, b) in sorted(info["by_type"].items()):
        con.print(
            f"  {t:<28} {n:>6} {'entry  ' if n == 1 else 'entries'} {b / 1e6:>9.1f} MB",
            markup=False,
        )
    if info["abandoned"]:
        con.print(
            f"  {_entries(info['abandoned'], 'unfinished ')} killed runs left in {store.tmp}: "
            f"{info['abandoned_bytes'] / 1e6:.1f} MB (the next prune removes them: "
            "`stereograph cache prune "
            f"--max-gb N`, or any run that stores something under a budget)",
            markup=False,
        )
    return 0


def cache_positionals_first(argv: list[str]) -> list[str]:
    """``cache prune --max-gb 5 PIPELINE`` as ``cache prune PIPELINE --max-gb 5``: argparse takes a
    sub-command's positionals in one run, so one after an option was refused as unrecognised."""
    head, options, rest = argv[:1], [], argv[1:]
    positionals = []
    i = 0
    while i < len(rest):
        a = rest[i]
        if a in ("--max-gb", "--cache-dir") and i + 1 < len(rest):
            options += rest[i : i + 2]
            i += 2
            continue
        (options if a.startswith("-") else positionals).append(a)
        i += 1
    return head + positionals + options


def _entries(n: int, what: str = "") -> str:
    """``1 entry``, ``2 entries`` (``what`` before the noun)."""
    return f"{n} {what}{'entry' if n == 1 else 'entries'}"
