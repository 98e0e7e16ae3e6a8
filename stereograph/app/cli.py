"""The ``stereograph`` command: its parser and the front every sub-command goes through.

Exit codes: 0 ok, 1 a node failed, 2 bad config or usage. A user error never shows a
traceback (``--debug`` does). The sub-commands live in ``run_command``, ``info_commands``,
``cache_command`` and ``compare``; this module stays light so that ``--help`` starts fast.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import os
import sys
import threading
import traceback
from typing import Any

from stereograph import __version__
from stereograph.app.cache_command import cache_positionals_first, cmd_cache
from stereograph.app.console import (
    add_executor_arguments,
    command_console,
    non_negative_int,
    size_gb,
)
from stereograph.app.console import seconds as seconds_arg
from stereograph.app.info_commands import (
    cmd_explain,
    cmd_graph,
    cmd_nodes,
    cmd_report,
    cmd_validate,
)
from stereograph.app.run_command import cmd_run
from stereograph.app.stop_signals import stop_signals_as_interrupt
from stereograph.core import registry
from stereograph.core.errors import ConfigError
from stereograph.core.threads import one_thread_each, pool_requested


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
    _add_run(_pipeline_command(sub, "run", "run a pipeline"))
    _add_looking_commands(sub)
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


def _pipeline_command(sub: Any, name: str, help_: str) -> argparse.ArgumentParser:
    """A sub-command that takes a pipeline file and ``--set``."""
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


def _add_run(sp: argparse.ArgumentParser) -> None:
    """``run``'s own options."""
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
    add_executor_arguments(sp, "per-item nodes")
    loop = sp.add_argument_group("the live loop (docs/live.md)")
    loop.add_argument(
        "--repeat",
        type=non_negative_int,
        metavar="N",
        help="run the live part (uncacheable nodes and "
        "their downstream) N times, 0 = until stopped; each cycle in cycles.jsonl",
    )
    loop.add_argument(
        "--stop-on-failure", action="store_true", help="--repeat: stop at the first failed cycle"
    )
    loop.add_argument(
        "--save-cycles",
        action="store_true",
        help="--repeat: write every cycle's live outputs, images included, into cycles/<n>/",
    )
    loop.add_argument(
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


def _add_looking_commands(sub: Any) -> None:
    """The commands that look without running: validate, graph, report, explain, nodes, cache."""
    _pipeline_command(sub, "validate", "check a pipeline without running it").set_defaults(
        fn=cmd_validate
    )
    sp = _pipeline_command(sub, "graph", "print the pipeline graph")
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
    sp = _pipeline_command(
        sub, "explain", "say for every node whether it is fresh or stale, and why"
    )
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


def main(argv: list[str] | None = None) -> int:
    if argv is not None:  # called from Python (tests, scripts): the process goes on
        return _main(argv)
    try:
        code = _main(sys.argv[1:])
    finally:
        # The command's process ends next: its objects need not be traced by the collections the
        # interpreter runs while it shuts down (~50 ms with pydantic and rich loaded); they are
        # still freed, files closed, atexit handlers run.
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
        argv = cache_positionals_first(argv)
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
                stop_signals_as_interrupt()
                if args.command in ("run", "compare")
                else contextlib.nullcontext()
            ),
        ):
            return int(args.fn(args) or 0)
    except ConfigError as e:
        _print_config_error(e)
        if debug:
            traceback.print_exc()
        return e.exit_code
    except KeyboardInterrupt:
        command_console(stderr=True).print(
            "interrupted: finished nodes are cached; run again to resume"
        )
        return 130
    except Exception as e:  # a bug: one paragraph, traceback only with --debug
        from rich.markup import escape

        command_console(stderr=True).print(
            f"[red]internal error:[/] {escape(f'{type(e).__name__}: {e}')}. "
            "Run again with --debug for the traceback, and report it."
        )
        if debug:
            traceback.print_exc()
        return 1


def _print_config_error(e: ConfigError) -> None:
    """A user's mistake on stderr: one paragraph per problem, and how many there are."""
    from rich.markup import escape

    from stereograph.core.errors import ConfigErrors

    err = command_console(stderr=True)
    for one in e.errors if isinstance(e, ConfigErrors) else [e]:
        err.print(f"[red]error:[/] {escape(str(one))}")
    if isinstance(e, ConfigErrors):
        err.print(f"{len(e.errors)} problems; fix them all, then run the command again.")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
