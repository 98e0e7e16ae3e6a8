"""``stereograph run``: a pipeline run (or an unchanged rerun replayed), its ``--repeat`` loop, what
it prints and its exit code.

Public: :func:`cmd_run`, :func:`finish_run`.
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Any

from stereograph.app.console import command_console, load_graph
from stereograph.app.progress import Mutable, PlainProgress, RichProgress
from stereograph.app.run_summary import (
    echo_entries,
    load_printing,
    print_closing,
    rendered_markdown,
)
from stereograph.app.stop_signals import stop_requested
from stereograph.core.errors import ConfigError, sentence


def _replayable(args) -> bool:
    """A plain ``run`` (no --no-cache, --only, --from or --repeat): one a rerun
    memo may answer (stereograph.app.rerun; STEREOGRAPH_NO_REPLAY=1 turns it off)."""
    return not (
        args.no_cache
        or args.only
        or getattr(args, "from")
        or args.repeat is not None
        or os.environ.get("STEREOGRAPH_NO_REPLAY", "") not in ("", "0")
    )


def cmd_run(args) -> int:
    from stereograph.app import rerun

    # (as the command starts: a plugin may add to sys.path)
    sys_path = rerun.fingerprint(args.pipeline)
    if _replayable(args):
        replayed = rerun.replay(args.pipeline, args.set or [], args.cache_dir, args.out)
        if replayed is not None:
            return finish_run(
                args,
                replayed,
                replayed.echo,
                lambda n: replayed.where[n],
                lambda n: replayed.upstream[n],
            )

    from stereograph.core.executors import workers_executor
    from stereograph.core.runner import run_graph

    graph = load_graph(args)
    if args.repeat is None and graph.doc.repeat is not None:  # the pipeline's own loop (`repeat:`)
        args.repeat = graph.doc.repeat
    con = command_console()
    prog = _progress(args, con)
    loop = _loop(args, con, None if args.verbose else prog.mute)
    executor = workers_executor(args.workers, args.dask)
    kw = dict(
        cache_dir=args.cache_dir,
        out_dir=args.out,
        use_cache=not args.no_cache,
        only=args.only,
        from_node=getattr(args, "from"),
        executor=executor,
        cycles=loop,
    )
    try:
        with _stdout_to_stderr(args.json):
            with prog:
                result = run_graph(graph, progress=prog, prepare=(load_printing,), **kw)
    except BaseException:  # (Ctrl-C: a pool's workers are ended, not waited for)
        executor.close(now=True)
        raise
    executor.close()
    live = frozenset(n for n, i in graph.nodes.items() if not i.spec.cacheable)
    echo = echo_entries(result, live) if not args.json else []
    if _replayable(args) and not args.json:
        _record_memo(args, graph, result, echo, sys_path)
    return finish_run(
        args,
        result,
        echo_entries(result) if live else echo,
        lambda n: graph.doc.where("nodes", n),
        lambda n: bool(graph.upstream(n)),
        loop,
    )


def _progress(args: Any, con: Any) -> Any:
    """A terminal gets live bars; a log, pipe or CI plain lines every few seconds (stderr with
    --json); a loop's cycles after the first, one line each (their nodes' lines with --verbose)."""
    interactive = sys.stdout.isatty() and not args.json and args.repeat is None
    return Mutable(
        RichProgress(con)
        if interactive
        else PlainProgress(sys.stderr if args.json else sys.stdout, args.progress_interval)
    )


def _record_memo(args: Any, graph: Any, result: Any, echo: list, sys_path: list) -> None:
    """The replay memo of a finished run (stereograph.app.rerun)."""
    from stereograph.app import rerun

    try:
        rerun.record(graph, result, rendered_markdown(echo, command_console()), sys_path)
    except Exception as e:  # the memo is only a fast path: the run's result stands without it
        if args.debug:
            command_console(stderr=True).print(
                f"note: no rerun memo recorded: {type(e).__name__}: {e}", markup=False
            )


@contextlib.contextmanager
def _stdout_to_stderr(active: bool):
    """With --json, standard output carries the JSON alone: what nodes print while they run (in this
    process, its workers, a local cluster's) goes to standard error, at the file-descriptor
    level."""
    if not active:
        yield
        return
    sys.stdout.flush()
    try:
        saved = os.dup(1)
        os.dup2(2, 1)
    except OSError:  # no real descriptors (an embedding host): print() is all there is to move
        with contextlib.redirect_stdout(sys.stderr):
            yield
        return
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 1)
        os.close(saved)


def finish_run(args, result, echo: list, where, has_upstream, loop=None) -> int:
    """What ``run`` prints after a run (or a replayed one), and its exit code."""
    if result.notes:
        err = command_console(stderr=True)
        for note in result.notes:
            err.print(f"note: {note}", markup=False)
    if args.json:
        print((result.out_dir / "run.json").read_text())
    else:
        print_closing(echo, result, loop)
    if loop is not None and (loop.interrupted or loop.completed):
        return 130 if loop.interrupted else 0
    if not result.ok:
        from rich.markup import escape

        err = command_console(stderr=True)
        failed = [r for r in result.reports.values() if r.status in ("failed", "partial")]
        for r in failed:
            more = (
                f" (and {r.items_failed - 1} more items: failed_items in run.json)"
                if r.items_failed > 1
                else ""
            )
            msg = sentence(f"{where(r.name)}: node '{r.name}' ({r.type}) failed: {r.error}{more}")
            if r.hint:
                msg += " Fix: " + sentence(r.hint)
            elif r.unexpected and not args.debug:
                msg += (
                    " This looks like a bug in the node rather than bad input: run again "
                    "with --debug for the "
                    "traceback (it is also in run.json), and report it."
                )
            err.print("[red]error:[/] " + escape(msg))
            if args.debug and r.trace:
                err.print(escape(r.trace))
        first = failed[0].name
        if has_upstream(first):
            err.print(
                "What finished is cached: after the fix, run the same command again and "
                "only the nodes the "
                "fix changes, and what depends on them, will run (`stereograph explain` "
                "shows which; "
                f"--from {first} forces '{first}' and its downstream).",
                markup=False,
            )
        else:
            err.print("After the fix, run the same command again.")
        return 1
    return 0


def _loop(args, con, after_cycle=None):
    """The ``--repeat`` loop (stereograph.app.loop), or None; ``after_cycle()`` is called as each
    cycle ends."""
    if args.repeat is None:
        return None
    if args.workers > 1 or args.dask:
        raise ConfigError(
            "a loop (--repeat, or the pipeline's own `repeat:`) runs every cycle in this "
            "process, so it "
            "cannot be combined with --workers or --dask.",
            hint="drop --workers / --dask",
        )
    from rich.markup import escape

    from stereograph.app.loop import Loop

    def on_cycle(c) -> None:
        if not args.json:
            con.print(escape(c.line()))
        if after_cycle is not None:
            after_cycle()

    return Loop(
        args.repeat,
        args.stop_on_failure,
        args.save_cycles,
        on_cycle=on_cycle,
        stop_requested=stop_requested,
    )
