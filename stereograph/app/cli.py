"""The ``stereograph`` command.

Exit codes: 0 ok, 1 a node failed, 2 bad config or usage. A user error never shows a
traceback (``--debug`` does).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import traceback
from pathlib import Path
from typing import Any

from stereograph import __version__
from stereograph.app.console import echo_entry, non_negative_int, positive_int, size_gb
from stereograph.app.console import seconds as seconds_arg
from stereograph.app.progress import Mutable, PlainProgress, RichProgress
from stereograph.core import registry
from stereograph.core.errors import ConfigError, sentence
from stereograph.core.threads import one_thread_each, pool_requested


def _console(stderr: bool = False):
    from stereograph.core.errors import console

    stream = sys.stderr if stderr else sys.stdout
    # logs and pipes get a wide table rather than rich's 80-column default
    width = None if stream.isatty() else PIPE_WIDTH
    # (user text is printed with its control characters escaped: a pipeline cannot drive the
    # terminal)
    return console(stderr=stderr, highlight=False, soft_wrap=True, width=width)


PIPE_WIDTH = 160  # columns of what a log, pipe or file gets


def _load_graph(args):
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    doc = load_pipeline(args.pipeline, getattr(args, "set", None) or [])
    return build_graph(doc)


def _print_warnings(graph, console) -> None:
    from rich.markup import escape

    for w in graph.warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")


def cmd_validate(args) -> int:
    from stereograph.core.errors import ConfigErrors
    from stereograph.core.graph import check_pipeline

    graph, problems = check_pipeline(args.pipeline, getattr(args, "set", None) or [])
    if problems:  # every one, not the first only (the summary line tells how many to fix)
        raise problems[0] if len(problems) == 1 else ConfigErrors(problems)
    con = _console()
    _print_warnings(graph, con)
    mapped = sum(1 for n in graph.nodes.values() if n.mapped)
    con.print(
        f"{graph.doc.path.name}: OK — {len(graph.nodes)} nodes ({mapped} per item), "
        f"order: {' -> '.join(graph.order)}",
        markup=False,
    )
    return 0


def cmd_graph(args) -> int:
    graph = _load_graph(args)
    if args.format in ("png", "svg"):
        return _graph_picture(graph, args)
    lines = []
    if args.format == "mermaid":
        lines.append("flowchart LR")
        for n, inst in graph.nodes.items():
            shape = (
                f'{n}[["{n}<br/>{inst.type}"]]' if inst.mapped else f'{n}["{n}<br/>{inst.type}"]'
            )
            lines.append(f"  {shape}")
        for n, inst in graph.nodes.items():
            for port, (src, out) in inst.inputs.items():
                lines.append(f"  {src} -- {out} → {port} --> {n}")
    else:
        lines.append(f'digraph "{graph.doc.name}" {{\n  rankdir=LR; node [shape=box];')
        for n, inst in graph.nodes.items():
            style = ', style="rounded,filled", fillcolor="#eef"' if inst.mapped else ""
            lines.append(f'  "{n}" [label="{n}\\n{inst.type}"{style}];')
        for n, inst in graph.nodes.items():
            for port, (src, out) in inst.inputs.items():
                lines.append(f'  "{src}" -> "{n}" [label="{out} → {port}"];')
        lines.append("}")
    print("\n".join(lines))
    return 0


def _graph_picture(graph, args) -> int:
    from stereograph.app import graph_picture
    from stereograph.app.page import write_html

    desc = graph_picture.describe(graph)
    path = Path(args.output or f"{graph.doc.name}.graph.{args.format}")
    try:
        if args.format == "svg":
            write_html(path, graph_picture.to_svg(desc))
        else:
            path.write_bytes(graph_picture.to_png(desc))
    except OSError as e:
        raise ConfigError(
            f"cannot write {path}: {e.strerror or e}", hint="choose another --output"
        ) from None
    print(path)
    return 0


def cmd_report(args) -> int:
    from stereograph.app.report import write_report

    print(write_report(args.run_dir))
    return 0


def _describe_params(
    model, prefix: str = "", defaults: Any = None
) -> list[tuple[str, str, str, str]]:
    """Rows (name, type, default, description [range]); nested models expand to dotted names,
    showing the defaults the parent gives them."""
    from pydantic import BaseModel

    from stereograph.core.api import type_name

    rows = []
    symbols = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<"}
    for name, f in model.model_fields.items():
        ann = f.annotation
        if defaults is not None and hasattr(defaults, name):
            value, has_default = getattr(defaults, name), True
        else:
            has_default = not f.is_required()
            value = f.get_default(call_default_factory=True) if has_default else None
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            rows += _describe_params(
                ann, f"{prefix}{name}.", value if isinstance(value, BaseModel) else None
            )
            continue
        default = repr(value) if has_default else "required"
        bounds = [
            f"{sym} {getattr(m, attr)}"
            for m in f.metadata
            for attr, sym in symbols.items()
            if getattr(m, attr, None) is not None
        ]
        desc = (f.description or "") + (f" [{', '.join(bounds)}]" if bounds else "")
        rows.append((prefix + name, type_name(ann), default, desc))
    return rows


def cmd_nodes(args) -> int:
    from rich.markup import escape
    from rich.table import Table

    con = _console()
    if args.name:
        spec = registry.get(args.name)
        con.print(
            f"[bold]{escape(spec.name)}[/]  (kind {escape(spec.kind)}, version "
            f"{escape(spec.version)}"
            f"{', never cached' if not spec.cacheable else ''})"
        )
        if spec.description:
            con.print(spec.description, markup=False)
        t = Table(
            "param",
            "type",
            "default",
            "description (unit) [range]",
            title="params",
            title_justify="left",
        )
        for row in _describe_params(spec.params):
            t.add_row(*(escape(c) for c in row))
        con.print(t)
        t = Table("input", "type", "mode", "description", title="inputs", title_justify="left")
        for n, i in spec.inputs.items():
            t.add_row(
                escape(n),
                escape(i.type),
                "gather (all items)" if i.gather else ("optional" if i.optional else "one"),
                escape(i.description),
            )
        con.print(t)
        t = Table("output", "type", "mode", "description", title="outputs", title_justify="left")
        for n, o in spec.outputs.items():
            t.add_row(
                escape(n),
                escape(o.type),
                ("collection " if o.collection else "") + ("saved" if o.save else ""),
                escape(o.description),
            )
        con.print(t)
        return 0
    t = Table("node type", "inputs → outputs", "description")
    # (an index: no node module imported when unchanged)
    for name, s in registry.summaries().items():
        if "error" in s:
            t.add_row(escape(name), "[red]unavailable[/]", escape(s["error"]))
        else:
            t.add_row(escape(name), escape(s["io"]), escape(s["description"]))
    con.print(t)
    return 0


SUMMARY_COLUMNS = ("node", "type", "status", "items", "seconds", "note")


def _summary_rows(result) -> list[list[str]]:
    """The run summary's rows, plain text (SUMMARY_COLUMNS)."""
    rows = []
    for r in result.reports.values():
        items = (
            ""
            if not r.items
            else (
                f"{r.items_ran} ran / {r.items}"
                + (f", {r.items_failed} failed" if r.items_failed else "")
            )
        )
        if r.error:
            note = r.error + (
                f" (+{r.items_failed - 1} more failed items: run.json)"
                if r.items_failed > 1
                else ""
            )
        elif r.messages:
            more = len(r.messages) - 1
            note = _clip(r.messages[0], 90) + (f" (+{more} more below)" if more else "")
        else:
            note = ""
        rows.append([r.name, r.type, r.status, items, f"{r.seconds:.2f}", _clip(note, 160)])
    return rows


def _clip(text: str, n: int) -> str:
    """``text`` in at most ``n`` characters, cut after a whole word and marked '…' (the whole
    text is in run.json, and an error's under the table)."""
    if len(text) <= n:
        return text
    cut = text[: n - 1]
    space = cut.rfind(" ")
    return (cut[:space] if space > n // 2 else cut).rstrip(" ,;:(") + "…"


ECHO_LIMIT = 6  # small terminal values echoed after a run
# a node's further messages printed under the table (a per-item node may have dozens)
NOTES_PER_NODE = 3


def _more_notes(result) -> list[str]:
    """A node's messages after the first (the table's note column shows the first): a warning such
    as 'rejected 1 view(s): 03' must not be only in run.json."""
    lines = []
    for r in result.reports.values():
        rest = [] if r.error else r.messages[1:]
        for m in rest[:NOTES_PER_NODE]:
            lines.append(f"note: {r.name}: {m}")
        if len(rest) > NOTES_PER_NODE:
            lines.append(f"note: {r.name}: +{len(rest) - NOTES_PER_NODE} more in run.json")
    return lines


def _summary_table(result, con) -> None:
    from rich.markup import escape
    from rich.table import Table

    colours = {
        "ran": "green",
        "cached": "cyan",
        "failed": "red",
        "partial": "yellow",
        "skipped": "magenta",
        "not selected": "dim",
    }
    t = Table(*SUMMARY_COLUMNS, title=f"run {result.run_id}", title_justify="left")
    for name, type_, status, items, seconds, note in _summary_rows(result):
        t.add_row(
            escape(name),
            escape(type_),
            f"[{colours.get(status, 'white')}]{status}[/]",
            items,
            seconds,
            escape(note),
        )
    con.print(t)


def _plain_closing(echo: list, result, loop, width: int) -> str | None:
    """What :func:`_print_echo`, :func:`_summary_table` and the last lines print, as plain text
    for a console that is not a terminal (stereograph.app.plaintext); None where rich must lay it
    out."""
    from stereograph.app import plaintext

    parts: list[str | None] = []
    for title, kind, text, *pre in [e for e in echo if e[0] != "live"][:ECHO_LIMIT]:
        parts.append(plaintext.rule(title, width))
        if pre and pre[0].get("console") == [width, None]:
            parts.append(pre[0]["text"].removesuffix("\n"))
        elif kind == "json":
            parts.append(plaintext.pretty(json.loads(text), width))
        else:
            return None
    parts.append(
        plaintext.table(f"run {result.run_id}", list(SUMMARY_COLUMNS), _summary_rows(result), width)
    )
    parts += [plaintext.line(n) for n in _more_notes(result)]
    if loop is not None:
        parts.append(
            plaintext.line(
                f"loop: {loop.summary()}; every cycle is in {result.out_dir / 'cycles.jsonl'}"
            )
        )
    parts.append(plaintext.line(f"outputs: {result.out_dir}"))
    if (result.out_dir / "report.html").is_file():
        parts.append(plaintext.line(f"report: {result.out_dir / 'report.html'}"))
    return None if None in parts else "\n".join(parts) + "\n"


def _echo_entries(result, live: frozenset[str] = frozenset()) -> list[list[str]]:
    """``[title, kind, text]`` of the small terminal outputs, in order; ``["live", node, output]``
    for those of the nodes in ``live`` (a rerun memo fills them in when they run again)."""
    entries: list[list[str]] = []
    for node, out, item in list(result.values):
        if node not in result.terminal or item is not None:
            continue  # (decided before loading: a cached rerun reads only what it shows)
        if node in live:
            entries.append(["live", node, out])
            continue
        shown = echo_entry(result.values[(node, out, item)])
        if shown is not None:
            entries.append([f"{node}.{out}", *shown])
            if sum(e[0] != "live" for e in entries) >= ECHO_LIMIT:
                break
    return entries


def _rendered_markdown(entries: list[list[str]], con) -> list[list[Any]]:
    """The entries with each text also as ``con`` renders it (its width and colours): a replayed
    rerun on the same kind of console prints that without parsing the Markdown or laying out the
    data again."""
    out: list[list[Any]] = []
    for e in entries:
        if e[0] != "live":
            with con.capture() as cap:
                _print_entry(con, e[1], e[2])
            e = [*e[:3], {"console": [con.width, con.color_system], "text": cap.get()}]
        out.append(e)
    return out


def _print_echo(entries: list[list[Any]], con) -> None:
    """Print the small terminal outputs (a location, joint angles, servo commands) for the user;
    larger ones are only in the output folder."""
    from rich.markup import escape

    for title, kind, text, *pre in [e for e in entries if e[0] != "live"][:ECHO_LIMIT]:
        con.rule(escape(title), align="left")
        if pre and pre[0].get("console") == [con.width, con.color_system]:
            con.file.write(pre[0]["text"])
        else:
            _print_entry(con, kind, text)


def _load_printing() -> None:
    """What printing a run's results imports (~0.15 s): loaded while a --workers run waits for its
    pool (run_graph's ``prepare``), not alone at its end."""
    import rich.markdown  # noqa: F401
    import rich.pretty  # noqa: F401
    import rich.table  # noqa: F401


def _print_entry(con, kind: str, text: str) -> None:
    if kind == "markdown":
        from rich.markdown import Markdown

        from stereograph.core.errors import printable

        con.print(Markdown(printable(text)))
    else:
        from rich.pretty import Pretty

        con.print(Pretty(json.loads(text), indent_guides=False, max_string=200))


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
            return _finish_run(
                args,
                replayed,
                replayed.echo,
                lambda n: replayed.where[n],
                lambda n: replayed.upstream[n],
            )

    from stereograph.core.executors import workers_executor
    from stereograph.core.runner import run_graph

    graph = _load_graph(args)
    if args.repeat is None and graph.doc.repeat is not None:  # the pipeline's own loop (`repeat:`)
        args.repeat = graph.doc.repeat
    con = _console()
    interactive = sys.stdout.isatty() and not args.json and args.repeat is None
    # a terminal gets live bars; a log, pipe or CI plain lines every few seconds (stderr with
    # --json); a loop's cycles after the first, one line each (their nodes' lines with --verbose)
    prog = Mutable(
        RichProgress(con)
        if interactive
        else PlainProgress(sys.stderr if args.json else sys.stdout, args.progress_interval)
    )
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
                result = run_graph(graph, progress=prog, prepare=(_load_printing,), **kw)
    except BaseException:  # (Ctrl-C: a pool's workers are ended, not waited for)
        executor.close(now=True)
        raise
    executor.close()
    live = frozenset(n for n, i in graph.nodes.items() if not i.spec.cacheable)
    echo = _echo_entries(result, live) if not args.json else []
    if _replayable(args) and not args.json:
        try:
            rerun.record(graph, result, _rendered_markdown(echo, _console()), sys_path)
        except Exception as e:  # the memo is only a fast path: the run's result stands without it
            if args.debug:
                _console(stderr=True).print(
                    f"note: no rerun memo recorded: {type(e).__name__}: {e}", markup=False
                )
    return _finish_run(
        args,
        result,
        _echo_entries(result) if live else echo,
        lambda n: graph.doc.where("nodes", n),
        lambda n: bool(graph.upstream(n)),
        loop,
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


def _finish_run(args, result, echo: list, where, has_upstream, loop=None) -> int:
    """What ``run`` prints after a run (or a replayed one), and its exit code."""
    if result.notes:
        err = _console(stderr=True)
        for note in result.notes:
            err.print(f"note: {note}", markup=False)
    if args.json:
        print((result.out_dir / "run.json").read_text())
    else:
        from stereograph.app import plaintext

        width = plaintext.plain_width(sys.stdout, PIPE_WIDTH)
        plain = _plain_closing(echo, result, loop, width) if width else None
        if plain is not None:  # (a log or pipe: rich would print the same, without colours)
            sys.stdout.write(plain)
            sys.stdout.flush()
        else:
            from rich.markup import escape

            con = _console()
            _print_echo(echo, con)
            _summary_table(result, con)
            for n in _more_notes(result):
                con.print(n, markup=False, highlight=False)
            if loop is not None:
                con.print(
                    escape(
                        f"loop: {loop.summary()}; every cycle is in "
                        f"{result.out_dir / 'cycles.jsonl'}"
                    )
                )
            con.print(f"outputs: {result.out_dir}", markup=False)
            if (result.out_dir / "report.html").is_file():
                con.print(f"report: {result.out_dir / 'report.html'}", markup=False)
    if loop is not None and (loop.interrupted or loop.completed):
        return 130 if loop.interrupted else 0
    if not result.ok:
        from rich.markup import escape

        err = _console(stderr=True)
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
        stop_requested=_stop_requested,
    )


_STOP: list[str] = []  # where each stop signal of this command landed (frame), in order


def _stop_requested() -> str | None:
    return _STOP[0] if _STOP else None


@contextlib.contextmanager
def _stop_signals_as_interrupt():
    """For ``run`` and ``compare``: SIGINT and SIGTERM both end the command as Ctrl-C does, as a
    ``KeyboardInterrupt`` raised in the running node (its cleanup runs: an arm is held, the run's
    ``run.json`` is written, the same command resumes), whatever the process inherited: a job
    started with ``&`` by a non-interactive shell inherits SIGINT *ignored*, and a supervisor may
    start it with the signals blocked. A worker process forked while this is installed keeps the
    default action."""
    main_pid = os.getpid()
    _STOP.clear()

    def on_signal(signum, frame):
        if os.getpid() != main_pid:  # a pool's worker: end as before (its pool is ended for it)
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        # where it landed: a loop that finds this set at its next node stops there
        # (stereograph.app.loop)
        _STOP.append(
            f"{frame.f_code.co_name} ({frame.f_code.co_filename}:{frame.f_lineno})"
            if frame
            else "?"
        )
        raise KeyboardInterrupt("SIGTERM" if signum == signal.SIGTERM else "")

    try:
        old = {
            signal.SIGTERM: signal.signal(signal.SIGTERM, on_signal),
            signal.SIGINT: signal.signal(signal.SIGINT, on_signal),
        }
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        for signum, handler in old.items():
            signal.signal(signum, handler)


CACHE_WAIT_S = 30.0  # cache prune / clear wait this long for running runs to end


def _cache_remove(args, store, root: Path, con) -> int:
    """``cache clear`` / ``cache prune``: once no run uses the cache (CacheBusy after
    CACHE_WAIT_S)."""
    if args.action == "clear":
        n = store.clear(wait_s=CACHE_WAIT_S)
        con.print(f"removed {n} entries from {root}", markup=False)
        return 0
    if args.max_gb is None:
        raise ConfigError(
            "cache prune needs --max-gb", hint="for example: stereograph cache prune --max-gb 5"
        )
    left = store.sweep_abandoned() if store.writable else 0  # (prune would, first: said apart here)
    n, freed = store.prune(int(args.max_gb * 1e9), wait_s=CACHE_WAIT_S)
    con.print(
        f"removed {n} least recently used entries ({freed / 1e6:.1f} MB) from {root}", markup=False
    )
    if left:
        con.print(
            f"removed {left / 1e6:.1f} MB of unfinished entries killed runs had left in "
            f"{store.tmp}",
            markup=False,
        )
    return 0


def cmd_explain(args) -> int:
    from rich.markup import escape

    from stereograph.app.explain import explain

    graph = _load_graph(args)
    con = _console()
    for v in explain(graph, args.cache_dir):
        state = "[cyan]fresh[/]" if v.fresh else "[yellow]stale[/]"
        why = (
            ("" if not v.reasons else f" ({v.reasons[0]})")
            if v.fresh
            else ": " + "; ".join(v.reasons)
        )
        con.print(f"{escape(f'{v.node:<16} {v.type:<26}')} {state}" + escape(why))
    return 0


def cmd_cache(args) -> int:
    from stereograph.core.cache import ArtifactStore
    from stereograph.core.config import load_pipeline
    from stereograph.core.run_state import default_cache_dir

    if args.cache_dir:
        root = Path(args.cache_dir)
    elif args.pipeline:
        root = default_cache_dir(load_pipeline(args.pipeline))
    else:
        from stereograph.core.project import cache_dir

        root = cache_dir(Path.cwd())
    store = ArtifactStore(root)
    con = _console()
    if args.action in ("clear", "prune"):
        from stereograph.core.cache import CacheBusy

        try:
            return _cache_remove(args, store, root, con)
        except CacheBusy:
            _console(stderr=True).print(
                f"error: a run is using the cache {root} (still after {CACHE_WAIT_S:g} "
                "s): nothing was removed, so "
                "that no entry disappears under it. Fix: run `stereograph cache "
                f"{args.action}` again when it has "
                "ended (a --repeat loop holds the cache until it stops).",
                markup=False,
            )
            return 1
    from stereograph.core.project import budget_bytes

    try:
        budget = budget_bytes(Path(args.pipeline).parent if args.pipeline else Path.cwd())
    except ValueError as e:
        raise ConfigError(
            f"cache budget: {e}", hint="set it in GB, for example STEREOGRAPH_CACHE_BUDGET_GB=4"
        ) from None
    info = store.info(budget)
    limit = (
        f" of a {budget / 1e9:g} GB budget (least recently used entries pruned after runs)"
        if budget
        else " (no budget)"
    )
    con.print(
        f"cache {info['root']}: {info['entries']} entries, {info['bytes'] / 1e6:.1f} MB{limit}",
        markup=False,
    )
    for t, (n, b) in sorted(info["by_type"].items()):
        con.print(f"  {t:<28} {n:>6} entries {b / 1e6:>9.1f} MB", markup=False)
    if info["abandoned"]:
        con.print(
            f"  {info['abandoned']} unfinished entries killed runs left in {store.tmp}: "
            f"{info['abandoned_bytes'] / 1e6:.1f} MB (the next prune removes them: "
            "`stereograph cache prune "
            f"--max-gb N`, or any run that stores something under a budget)",
            markup=False,
        )
    return 0


def _cache_positionals_first(argv: list[str]) -> list[str]:
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


def build_parser(lazy: bool = False) -> argparse.ArgumentParser:
    """The command's parser; ``lazy`` leaves out what needs heavy imports (``compare``'s own
    options: ``main`` builds the full parser when the line names it), so ``--help`` starts fast."""
    p = argparse.ArgumentParser(
        prog="stereograph",
        description="Stereo localisation and robot-arm picking as a "
        "config-driven processing graph.",
    )
    p.add_argument("--version", action="version", version=f"stereograph {__version__}")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.add_argument(
        "--allow-plugins",
        action="store_true",
        help="import the Python modules a pipeline lists under 'plugins:' (runs their code: "
        "only for "
        "pipelines you trust; also STEREOGRAPH_ALLOW_PLUGINS=1)",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    def pipeline_cmd(name: str, help_: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help_)
        sp.add_argument("pipeline", help="pipeline YAML file")
        sp.add_argument(
            "--set",
            action="append",
            metavar="NODE.PARAM=VALUE",
            help="override a param (value parsed as YAML), or NODE.type=NAME; repeatable",
        )
        sp.add_argument("--debug", action="store_true", help="show tracebacks")
        return sp

    sp = pipeline_cmd("run", "run a pipeline")
    sp.add_argument("--out", help="output folder (default <project>/runs/<name>/<run-id>)")
    sp.add_argument(
        "--cache-dir",
        help="artifact cache (default: the project's .stereograph/cache, or "
        "STEREOGRAPH_CACHE_DIR; see docs/cache.md)",
    )
    sp.add_argument("--no-cache", action="store_true", help="compute everything, store nothing")
    sp.add_argument("--json", action="store_true", help="print run.json instead of the table")
    sp.add_argument("--only", metavar="NODE", help="run only NODE and its upstream")
    sp.add_argument(
        "--from", metavar="NODE", help="recompute NODE and its downstream even if cached"
    )
    sp.add_argument(
        "--workers", type=positive_int, default=1, help="processes for per-item nodes (default 1)"
    )
    sp.add_argument(
        "--dask",
        metavar="ADDRESS",
        help="run per-item nodes on a Dask cluster "
        "('local' starts one with --workers processes; needs the 'dask' extra; a remote "
        "cluster must "
        "see the cache and run folder on shared storage: docs/parallel.md)",
    )
    sp.add_argument(
        "--repeat",
        type=non_negative_int,
        metavar="N",
        help="run the live part (uncacheable nodes and "
        "their downstream) N times, 0 = until stopped; each cycle in cycles.jsonl",
    )
    sp.add_argument(
        "--stop-on-failure", action="store_true", help="--repeat: stop at the first failed cycle"
    )
    sp.add_argument(
        "--save-cycles",
        action="store_true",
        help="--repeat: write every cycle's live outputs, images included, into cycles/<n>/",
    )
    sp.add_argument(
        "--verbose",
        action="store_true",
        help="--repeat: a line per node in every cycle, not only in "
        "the first (the others get one line per cycle)",
    )
    sp.add_argument(
        "--progress-interval",
        type=seconds_arg,
        default=5.0,
        metavar="SECONDS",
        help="when output is not a terminal: seconds between progress lines per node (default 5)",
    )
    sp.set_defaults(fn=cmd_run)
    pipeline_cmd("validate", "check a pipeline without running it").set_defaults(fn=cmd_validate)
    sp = pipeline_cmd("graph", "print the pipeline graph")
    sp.add_argument(
        "--format",
        choices=["mermaid", "dot", "png", "svg"],
        default="mermaid",
        help="text (mermaid, dot) on stdout, or a picture (png, svg) written to --output",
    )
    sp.add_argument(
        "--output",
        "-o",
        metavar="FILE",
        help="png/svg: the file (default <pipeline>.graph.<format>)",
    )
    sp.set_defaults(fn=cmd_graph)
    sp = sub.add_parser("report", help="(re)build report.html in a run folder")
    sp.add_argument("run_dir", help="the folder a run wrote (it holds run.json)")
    sp.set_defaults(fn=cmd_report)
    sp = pipeline_cmd("explain", "say for every node whether it is fresh or stale, and why")
    sp.add_argument("--cache-dir")
    sp.set_defaults(fn=cmd_explain)
    sp = sub.add_parser("nodes", help="list node types, or show one's params")
    sp.add_argument("name", nargs="?")
    sp.set_defaults(fn=cmd_nodes)
    sp = sub.add_parser("cache", help="cache info | prune --max-gb N | clear (the project's cache)")
    sp.add_argument("action", choices=["info", "prune", "clear"])
    sp.add_argument(
        "--max-gb",
        type=size_gb,
        help="prune: keep the most recently used entries up to this size (GB, 0 or more)",
    )
    sp.add_argument("pipeline", nargs="?", help="use this pipeline's default cache")
    sp.add_argument("--cache-dir")
    sp.set_defaults(fn=cmd_cache)
    if lazy:
        sub.add_parser(
            "compare",
            help="run every combination of --vary settings and compare accuracy",
            add_help=False,
        )
    else:
        try:
            from stereograph.app import compare as compare_mod

            compare_mod.add_subcommand(sub)
        except (ImportError, AttributeError):
            pass
    for name in registry.commands():
        sp = sub.add_parser(
            name, help=f"(from a node package) see `stereograph {name} --help`", add_help=False
        )
        sp.add_argument("rest", nargs=argparse.REMAINDER)
        sp.set_defaults(plugin=name)
    return p


def main(argv: list[str] | None = None) -> int:
    if argv is not None:  # called from Python (tests, scripts): the process goes on
        return _main(argv)
    try:
        code = _main(sys.argv[1:])
    finally:
        # The command's process ends next: its objects need not be traced by the collections the
        # interpreter runs while it shuts down (~50 ms with pydantic and rich loaded); they are
        # still freed, files closed, atexit handlers run.
        import gc

        gc.freeze()
    _end_process(code)
    return code


def _end_process(code: int) -> None:
    """End the command's process at once, after what must happen at its end: the atexit handlers
    (a Dask cluster's, multiprocessing's, temporary folders') and the standard streams flushed.

    What Python's own shut-down would do next is free every object and unload every module: ~0.2 s
    with OpenCV, matplotlib, pydantic and rich loaded, after every command, the run's time included
    (mypy ends its process the same way). Not while a thread that is not a daemon still runs (the
    normal shut-down waits for it), nor when flushing fails (a closed pipe: the normal one says so).
    """
    import atexit
    import threading

    if any(
        t is not threading.main_thread() and t.is_alive() and not t.daemon
        for t in threading.enumerate()
    ):
        return
    try:
        # (they are cleared: a normal shut-down after this does not run them twice)
        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
    except Exception:  # noqa: BLE001 -- the normal shut-down then runs and reports it
        return
    os._exit(code)


def _main(argv: list[str]) -> int:
    argv = list(argv)
    if pool_requested(argv):
        # this process too (its head shares the cores with the workers), before NumPy loads
        one_thread_each()
    parser = build_parser(lazy="compare" not in argv)
    if argv and argv[0] in registry.commands():
        ep = registry.commands()[argv[0]]
        return int(ep.load()(argv[1:]) or 0)
    # a global option, accepted anywhere on the line (every sub-command loads pipelines)
    allow_plugins = "--allow-plugins" in argv or os.environ.get(
        "STEREOGRAPH_ALLOW_PLUGINS", ""
    ) in ("1", "yes", "true")
    argv = [a for a in argv if a != "--allow-plugins"]
    if argv and argv[0] == "cache":
        argv = _cache_positionals_first(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:
        return int(e.code or 0) and 2
    if not getattr(args, "fn", None):
        parser.print_help()
        return 2
    debug = getattr(args, "debug", False) or "--debug" in argv
    args.debug = debug  # `stereograph --debug run X` and `stereograph run X --debug` alike
    try:
        with (
            registry.plugins_allowed(allow_plugins),
            (
                _stop_signals_as_interrupt()
                if args.command in ("run", "compare")
                else contextlib.nullcontext()
            ),
        ):
            return int(args.fn(args) or 0)
    except ConfigError as e:
        from rich.markup import escape

        from stereograph.core.errors import ConfigErrors

        err = _console(stderr=True)
        for one in e.errors if isinstance(e, ConfigErrors) else [e]:
            err.print(f"[red]error:[/] {escape(str(one))}")
        if isinstance(e, ConfigErrors):
            err.print(f"{len(e.errors)} problems; fix them all, then run the command again.")
        if debug:
            traceback.print_exc()
        return e.exit_code
    except KeyboardInterrupt:
        _console(stderr=True).print("interrupted: finished nodes are cached; run again to resume")
        return 130
    except Exception as e:  # a bug: one paragraph, traceback only with --debug
        from rich.markup import escape

        _console(stderr=True).print(
            f"[red]internal error:[/] {escape(f'{type(e).__name__}: {e}')}. "
            "Run again with --debug for the traceback, and report it."
        )
        if debug:
            traceback.print_exc()
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
