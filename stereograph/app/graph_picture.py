"""The pipeline DAG as a picture: SVG (hand-written, no dependency) or PNG (matplotlib).

Works on a plain description -- ``{node: {"type": str, "mapped": bool, "inputs": {port: [src,
out]}}}`` -- so that it can draw a :class:`~stereograph.core.graph.Graph` (``stereograph graph
--format svg``) and a finished run from its ``run.json`` alike (``report.html``), and knows nothing
of what the nodes do. Layout, top to bottom, layered as Graphviz's dot does (:func:`layout`): a long
wire passes through a slot of its own in each row it crosses, beside the boxes, never across one.
"""

from __future__ import annotations

import graphlib
import heapq
import html
import io
from typing import Any

BOX_W, BOX_H, GAP_X, GAP_Y, PAD, SLOT_W = 170, 46, 24, 40, 12, 14
MAX_SLOTS = 20000  # row crossings of long wires laid out (beyond: straight wires)
STATUS_FILL = {
    "ran": "#d9f2d9",
    "cached": "#e3ecfa",
    "partial": "#fde9c4",
    "failed": "#f8d0d0",
    "skipped": "#e6e6e6",
    "not selected": "#f4f4f4",
}


def describe(graph: Any) -> dict[str, dict[str, Any]]:
    """The plain description of a validated :class:`~stereograph.core.graph.Graph`."""
    return {
        n: {
            "type": inst.type,
            "mapped": bool(inst.mapped),
            "inputs": {p: [s, o] for p, (s, o) in inst.inputs.items()},
        }
        for n, inst in graph.nodes.items()
    }


def dag(nodes: dict[str, dict[str, Any]]) -> dict[str, dict[str, None]]:
    """The wires between the described nodes as a DAG: each node's successors, in the listed
    order. A description read from a foreign ``run.json`` may hold a cycle: the wires a
    depth-first walk finds closing one are left out."""
    succ: dict[str, dict[str, None]] = {n: {} for n in nodes}
    for src, _, dst, _ in _edges(nodes):
        if src != dst:
            succ[src][dst] = None
    state: dict[str, int] = {}  # 1: on the walk's path, 2: done
    back = []
    for root in nodes:
        if root in state:
            continue
        state[root] = 1
        stack = [(root, iter(succ[root]))]  # (edges are removed only after the walk)
        while stack:
            n, rest = stack[-1]
            for m in rest:
                if state.get(m) == 1:
                    back.append((n, m))
                elif m not in state:
                    state[m] = 1
                    stack.append((m, iter(succ[m])))
                    break
            else:
                state[n] = 2
                stack.pop()
    for n, m in back:
        succ[n].pop(m, None)
    return succ


def topological_order(succ: dict[str, dict[str, None]], key: Any) -> list[str]:
    """The nodes of :func:`dag`, each after those it reads; of the nodes ready, the smallest
    ``key`` first (NetworkX's lexicographical topological sort; the standard library's
    ``graphlib`` here: a replayed rerun writes its page without importing NetworkX)."""
    sorter = graphlib.TopologicalSorter(_predecessors(succ))
    sorter.prepare()
    ready = [(key(n), n) for n in sorter.get_ready()]
    heapq.heapify(ready)
    order = []
    while ready:
        n = heapq.heappop(ready)[1]
        order.append(n)
        sorter.done(n)
        for m in sorter.get_ready():
            heapq.heappush(ready, (key(m), m))
    return order


def _predecessors(succ: dict[str, dict[str, None]]) -> dict[str, list[str]]:
    preds: dict[str, list[str]] = {n: [] for n in succ}
    for n, after in succ.items():
        for m in after:
            preds[m].append(n)
    return preds


def _rows(nodes: dict[str, dict[str, Any]]) -> dict[str, int]:
    """Each node's row: the longest path that reaches it; a node without inputs (an arm model) sits
    just above its first consumer."""
    succ = dag(nodes)
    index = {n: i for i, n in enumerate(nodes)}
    preds, row = _predecessors(succ), {}
    for n in topological_order(succ, index.__getitem__):
        row[n] = 1 + max((row[p] for p in preds[n]), default=-1)
    for n in nodes:
        users = [row[m] for m in succ[n]]
        if not preds[n] and users:
            row[n] = max(0, min(users) - 1)
    return row


def _edges(nodes: dict[str, dict[str, Any]]):
    for n, d in nodes.items():
        for port, (src, out) in d.get("inputs", {}).items():
            if src in nodes:
                yield src, out, n, port


def layout(
    nodes: dict[str, dict[str, Any]],
) -> tuple[dict[str, tuple[float, float]], list, tuple[float, float]]:
    """Box corners (top-left, px), each wire as ``(src, out, dst, port, [(x, y), ...])``, and the
    size (px).

    Layered, as Graphviz's dot lays out a DAG: a node's row is its longest path from a source; a
    wire that spans rows passes through a narrow slot in every row between (so it never crosses a
    box); each row is ordered by the mean position of what it is wired to, a few sweeps down and up
    (fewer crossings); slots and boxes are then spaced out in their row's order.
    """
    row = _rows(nodes)
    edges = list(_edges(nodes))
    n_rows = max(row.values(), default=-1) + 1
    order, up, chains = _row_members(nodes, row, edges, n_rows)
    _sweep(order, up, n_rows)
    pos, width = _place(order, nodes)
    n_in = {n: len(d.get("inputs", {})) for n, d in nodes.items()}
    k_in: dict[str, int] = {}
    wires = []
    for (src, out, dst, port), chain in zip(edges, chains):
        k = k_in[dst] = k_in.get(dst, 0) + 1  # each input arrives at its own point on the box's top
        (x0, y0), (x1, y1) = pos[src], pos[dst]
        pts = [(x0 + BOX_W / 2, y0 + BOX_H)]
        for slot in chain[1:-1]:  # through the slot's row, top to bottom, in its lane
            sx, sy = pos[slot]
            pts += [(sx + SLOT_W / 2, sy), (sx + SLOT_W / 2, sy + BOX_H)]
        pts.append((x1 + BOX_W * k / (n_in[dst] + 1), y1))
        wires.append((src, out, dst, port, pts))
    h = PAD + max(n_rows, 1) * (BOX_H + GAP_Y) - GAP_Y + PAD
    return {n: pos[n] for n in nodes}, wires, (max(width, PAD + BOX_W) + PAD, h)


def _row_members(
    nodes: dict[str, dict[str, Any]], row: dict[str, int], edges: list, n_rows: int
) -> tuple[list[list[Any]], dict[Any, list[Any]], list[list[Any]]]:
    """Per row, its boxes and the ``(edge index, row)`` slots of the wires that pass through it;
    what feeds each box or slot from the row above; each wire's chain of boxes and slots."""
    order: list[list[Any]] = [[] for _ in range(n_rows)]
    for n in nodes:
        order[row[n]].append(n)
    up: dict[Any, list[Any]] = {}
    chains = []
    # (a huge foreign run.json: past MAX_SLOTS the long wires are drawn straight, the page stays
    # fast)
    slots = sum(max(0, row[d] - row[s_] - 1) for s_, _, d, _ in edges) <= MAX_SLOTS
    for i, (src, _out, dst, _port) in enumerate(edges):
        chain = [src] + ([(i, r) for r in range(row[src] + 1, row[dst])] if slots else []) + [dst]
        for r, slot in enumerate(chain[1:-1], row[src] + 1):
            order[r].append(slot)
        for a_, b_ in zip(chain, chain[1:]):
            # (a long wire drawn straight links no rows)
            if _row_of(b_, row) == _row_of(a_, row) + 1:
                up.setdefault(b_, []).append(a_)
        chains.append(chain)
    return order, up, chains


def _sweep(order: list[list[Any]], up: dict[Any, list[Any]], n_rows: int) -> None:
    """Order each row by the mean position of what it is wired to: barycentre sweeps, down then
    up (fewer crossings)."""
    down: dict[Any, list[Any]] = {}
    for b_, feeds in up.items():
        for a_ in feeds:
            down.setdefault(a_, []).append(b_)
    for _ in range(4):
        for rows_, links in ((range(1, n_rows), up), (range(n_rows - 2, -1, -1), down)):
            for r in rows_:
                near = {v: k for k, v in enumerate(order[r - 1 if links is up else r + 1])}
                at = {v: k for k, v in enumerate(order[r])}
                order[r].sort(
                    key=lambda v: (
                        sum(near[u] for u in links.get(v, ())) / len(links[v])
                        if links.get(v)
                        else at[v]
                    )
                )


def _place(
    order: list[list[Any]], nodes: dict[str, dict[str, Any]]
) -> tuple[dict[Any, tuple[float, float]], float]:
    """Top-left corner of every box and slot, spaced out in its row's order; the widest row."""
    pos: dict[Any, tuple[float, float]] = {}
    width = 0.0
    for r, items in enumerate(order):
        x = PAD
        for v in items:
            pos[v] = (x, PAD + r * (BOX_H + GAP_Y))
            x += BOX_W if v in nodes else SLOT_W
            width = max(width, x)
            x += GAP_X if v in nodes else 0
    return pos, width


def _row_of(v: Any, row: dict[str, int]) -> int:
    """The row of a box (a node's name) or of a slot (``(edge index, row)``)."""
    return v[1] if isinstance(v, tuple) else row[v]


def to_svg(nodes: dict[str, dict[str, Any]], status: dict[str, str] | None = None) -> str:
    """An SVG document; ``status`` (node -> ran / cached / failed ...) colours the boxes."""
    pos, wires, (w, h) = layout(nodes)
    e = html.escape
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="sg-graph" width="{w:.0f}" '
        f'height="{h:.0f}" '
        f'viewBox="0 0 {w:.0f} {h:.0f}" font-family="sans-serif">',
        '<defs><marker id="sg-arrow" viewBox="0 0 10 10" refX="10" refY="5" markerWidth="7" '
        'markerHeight="7" orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" '
        'fill="#555"/></marker></defs>',
    ]
    for src, out, dst, port, pts in wires:
        d = "M" + " L".join(f"{x:.0f},{y:.0f}" for x, y in pts)
        parts.append(
            f'<path d="{d}" fill="none" stroke="#555" stroke-width="1.2" '
            'marker-end="url(#sg-arrow)">'
            f"<title>{e(f'{src}.{out} -> {dst}.{port}')}</title></path>"
        )
    for n, d in nodes.items():
        x, y = pos[n]
        st = (status or {}).get(n)
        fill = STATUS_FILL.get(st or "", "#ffffff")
        tip = (
            f"{n} ({d.get('type', '?')})"
            + (f": {st}" if st else "")
            + (", once per item" if d.get("mapped") else "")
        )
        parts.append(f'<g class="sg-node" data-node="{e(n)}"><title>{e(tip)}</title>')
        if d.get("mapped"):  # a stacked look for per-item nodes
            parts.append(
                f'<rect x="{x + 4:.0f}" y="{y + 4:.0f}" width="{BOX_W}" height="{BOX_H}" rx="6" '
                f'fill="{fill}" stroke="#777"/>'
            )
        parts.append(
            f'<rect x="{x:.0f}" y="{y:.0f}" width="{BOX_W}" height="{BOX_H}" rx="6" fill="{fill}" '
            f'stroke="#333"/>'
        )
        parts.append(
            f'<text x="{x + BOX_W / 2:.0f}" y="{y + 19:.0f}" text-anchor="middle" font-size="13" '
            f'font-weight="bold">{e(_clip(n, 22))}</text>'
        )
        parts.append(
            f'<text x="{x + BOX_W / 2:.0f}" y="{y + 36:.0f}" text-anchor="middle" font-size="11" '
            f'fill="#444">{e(_clip(str(d.get("type", "")), 26))}</text></g>'
        )
    parts.append("</svg>")
    return "\n".join(parts)


def _clip(text: str, n: int) -> str:
    return text if len(text) <= n else text[: n - 1] + "…"


def to_png(
    nodes: dict[str, dict[str, Any]], status: dict[str, str] | None = None, dpi: int = 100
) -> bytes:
    """The same picture as :func:`to_svg`, rendered by matplotlib (Agg) as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.patches import FancyArrowPatch

    pos, wires, (w, h) = layout(nodes)
    fig = Figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)  # y down, as in the SVG
    ax.axis("off")
    for *_, pts in wires:
        xs, ys = zip(*pts)
        ax.plot(xs[:-1], ys[:-1], color="#555", lw=1.0)
        ax.add_patch(
            FancyArrowPatch(
                pts[-2],
                pts[-1],
                arrowstyle="-|>",
                mutation_scale=10,
                color="#555",
                lw=1.0,
                shrinkA=0,
                shrinkB=0,
            )
        )
    for n, d in nodes.items():
        _draw_box(ax, pos[n], n, d, STATUS_FILL.get((status or {}).get(n) or "", "#ffffff"))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def _draw_box(ax: Any, corner: tuple[float, float], n: str, d: dict[str, Any], fill: str) -> None:
    """One node's box on matplotlib axes (a shadow box behind a per-item node), name, type."""
    from matplotlib.patches import FancyBboxPatch

    x, y = corner
    if d.get("mapped"):
        ax.add_patch(
            FancyBboxPatch(
                (x + 4, y + 4),
                BOX_W,
                BOX_H,
                boxstyle="round,pad=0,rounding_size=6",
                fc=fill,
                ec="#777",
            )
        )
    ax.add_patch(
        FancyBboxPatch(
            (x, y), BOX_W, BOX_H, boxstyle="round,pad=0,rounding_size=6", fc=fill, ec="#333"
        )
    )
    ax.text(
        x + BOX_W / 2,
        y + 17,
        _clip(n, 22),
        ha="center",
        va="center",
        fontsize=9.5,
        weight="bold",
    )
    ax.text(
        x + BOX_W / 2,
        y + 34,
        _clip(str(d.get("type", "")), 26),
        ha="center",
        va="center",
        fontsize=8,
        color="#444",
    )
