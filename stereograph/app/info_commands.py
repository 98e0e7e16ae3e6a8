"""The commands that look without running: ``validate``, ``graph``, ``report``, ``nodes`` and
``explain``.

Public: :func:`cmd_validate`, :func:`cmd_graph`, :func:`cmd_report`, :func:`cmd_nodes`,
:func:`cmd_explain`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stereograph.app.console import command_console, load_graph
from stereograph.app.node_index import summaries
from stereograph.core import registry
from stereograph.core.errors import ConfigError


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
    con = command_console()
    _print_warnings(graph, con)
    mapped = sum(1 for n in graph.nodes.values() if n.mapped)
    con.print(
        f"{graph.doc.path.name}: OK — {len(graph.nodes)} nodes ({mapped} per item), "
        f"order: {' -> '.join(graph.order)}",
        markup=False,
    )
    return 0


def cmd_graph(args) -> int:
    graph = load_graph(args)
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

    con = command_console()
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
    for name, s in summaries().items():
        if "error" in s:
            t.add_row(escape(name), "[red]unavailable[/]", escape(s["error"]))
        else:
            t.add_row(escape(name), escape(s["io"]), escape(s["description"]))
    con.print(t)
    return 0


def cmd_explain(args) -> int:
    from rich.markup import escape

    from stereograph.app.explain import explain

    graph = load_graph(args)
    con = command_console()
    for v in explain(graph, args.cache_dir):
        state = "[cyan]fresh[/]" if v.fresh else "[yellow]stale[/]"
        why = (
            ("" if not v.reasons else f" ({v.reasons[0]})")
            if v.fresh
            else ": " + "; ".join(v.reasons)
        )
        con.print(f"{escape(f'{v.node:<16} {v.type:<26}')} {state}" + escape(why))
    return 0
