"""What the command line accepts and shows: argument types, the console, how one value is echoed.

Shared by the sub-commands (``run``, ``compare``, the others) and a replayed rerun, so that each
reads ``--workers`` and echoes a result the same way. Public names:
:func:`positive_int`, :func:`non_negative_int`, :func:`size_gb`, :func:`seconds`,
:func:`add_executor_arguments`, :func:`echo_entry`, :func:`console`, :func:`command_console`,
:func:`load_graph`, :data:`PIPE_WIDTH`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any


def positive_int(text: str, least: int = 1, what: str = "at least 1") -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"must be {what} (got {value})")
    return value


def add_executor_arguments(parser: argparse.ArgumentParser, work: str) -> None:
    """``--workers`` and ``--dask``: where a command runs ``work`` (its per-item part)."""
    parser.add_argument(
        "--workers", type=positive_int, default=1, help=f"processes for {work} (default 1)"
    )
    parser.add_argument(
        "--dask",
        metavar="ADDRESS",
        help=f"run {work} on a Dask cluster ('local' starts one with --workers processes; needs "
        "the 'dask' extra; a remote cluster must see the cache and run folder on shared storage: "
        "docs/parallel.md)",
    )


def non_negative_int(text: str) -> int:
    return positive_int(text, 0, "0 (until stopped) or more")


def size_gb(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of GB") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(
            f"must be a size in GB, 0 or more (got {text}; 0 empties the cache)"
        )
    return value


def seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a number of seconds above 0 (got {text})")
    return value


def echo_entry(v: Any) -> tuple[str, str] | None:
    """How the console shows one small terminal value: ``("markdown", text)`` for a report that
    renders itself, ``("json", text)`` for plain data, None for what only the output folder
    holds."""
    from stereograph.core.outputs import is_file_value, to_json

    if not isinstance(v, (dict, list, float, int, str)):
        return None
    # a file the node encoded (YAML export, PLY cloud): in the output folder, not the console
    if is_file_value(v):
        return None
    if isinstance(v, dict) and isinstance(v.get("markdown"), str):
        return "markdown", v["markdown"]  # a report that renders itself: shown as the table it is
    arrays: dict = {}
    text = json.dumps(_glance(to_json(v, arrays)), default=str)
    if (arrays or len(text) > 3000) and isinstance(v, dict):
        # big artifacts (a calibration, say): show their scalar facts only
        small = {
            k: x
            for k, x in v.items()
            if isinstance(x, (int, float, str, bool))
            or (
                isinstance(x, (list, tuple))
                and len(x) <= 6
                and all(isinstance(y, (int, float, str, bool)) for y in x)
            )
        }
        if not small:
            return None
        text = json.dumps(_glance(to_json(small, {})), default=str)
    elif arrays or len(text) > 3000:
        return None
    return "json", text


def _glance(x: Any) -> Any:
    """Floats to 4 significant digits, whole digits kept (-0.0587, 514.9, 1234567.0): the console
    is for a glance; the run folder keeps every digit."""
    if isinstance(x, float) and math.isfinite(x) and x != 0:
        return round(x, max(0, 3 - math.floor(math.log10(abs(x)))))
    if isinstance(x, dict):
        return {k: _glance(y) for k, y in x.items()}
    if isinstance(x, list):
        return [_glance(y) for y in x]
    return x


_CONSOLE_CLASS: Any = None


def console(**kw: Any) -> Any:
    """A rich ``Console`` that prints every text through :func:`printable` (its own colours stay),
    no emoji codes."""
    global _CONSOLE_CLASS
    if _CONSOLE_CLASS is None:
        from rich.console import Console

        from stereograph.core.errors import printable

        class _Console(Console):
            # print(), table cells, titles, rules
            def render_str(self, text: str, *a: Any, **k: Any) -> Any:
                return super().render_str(printable(text), *a, **k)

        _CONSOLE_CLASS = _Console
    # (rich would show a user's ':ab:' -- in a value, a path -- as an emoji)
    kw.setdefault("emoji", False)
    return _CONSOLE_CLASS(**kw)


PIPE_WIDTH = 160  # columns of what a log, pipe or file gets


def command_console(stderr: bool = False):
    """A rich console for a command's output: wide in a log or pipe, user text escaped."""
    stream = sys.stderr if stderr else sys.stdout
    # logs and pipes get a wide table rather than rich's 80-column default
    width = None if stream.isatty() else PIPE_WIDTH
    # (user text is printed with its control characters escaped: a pipeline cannot drive the
    # terminal)
    return console(stderr=stderr, highlight=False, soft_wrap=True, width=width)


def load_graph(args: Any) -> Any:
    """The graph of ``args.pipeline`` with its ``--set`` overrides."""
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    doc = load_pipeline(args.pipeline, getattr(args, "set", None) or [])
    return build_graph(doc)
