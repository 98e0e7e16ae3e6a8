"""``report.accuracy``: localisation error statistics over a dataset with ground truth.

A reduce over all ``Location`` items: per axis (x, y, z; cm, in each location's frame) the
mean, standard deviation, max |error| and RMS of (measured - true), in the thesis's table
form, for the items of the chosen split that were found and have a truth. Outputs: the
``AccuracyReport`` (JSON), ``locations`` (one record per pair: the ``locations.json`` of the
run), a figure (error histograms per axis + error vs distance; matplotlib Agg rendered to a
BGR image) and, in the node's output folder, ``accuracy.md``.
"""

from __future__ import annotations

import re
from typing import Literal

import numpy as np

from nodes.contracts.drawing import load_figures
from nodes.contracts.reasons import group_reasons
from stereograph.api import Field, In, NodeError, Out, Params, node


class AccuracyParams(Params):
    """Parameters of ``report.accuracy``."""

    split: Literal["test", "train", "all"] = Field(
        "test", description="Which items to evaluate (split name, or all)."
    )
    title: str = Field("Localisation error", description="Title of the table and figure (text).")
    figure: bool = Field(True, description="Render the matplotlib figure (bool).")
    by_kind: bool = Field(
        False,
        description="Also per kind of pair (its id without the trailing number: "
        "source.synthetic's touching_ball003 is a touching_ball) in the "
        "metrics: found_<kind> (rate) and off_1cm_<kind> (found, > 1 cm off).",
    )


AXES = ("x", "y", "z")
MAX_REASON_LINES = 3  # kinds of not-found reason listed in the Markdown (report.json lists all)


def error_table(measured_cm: np.ndarray, true_cm: np.ndarray) -> dict:
    """Per-axis error statistics (cm).

    Parameters
    ----------
    measured_cm, true_cm : (N, 3) arrays, cm.

    Returns
    -------
    ``{"x": {"mean_cm", "std_cm", "max_abs_cm", "rms_cm"}, "y": ..., "z": ...}``; the std is
    the sample standard deviation (ddof=1, as the thesis's tables); None entries when N = 0.
    """
    err = np.asarray(measured_cm, float) - np.asarray(true_cm, float)
    out = {}
    for i, ax in enumerate(AXES):
        e = err[:, i] if len(err) else np.zeros(0)
        if len(e) == 0:
            out[ax] = {"mean_cm": None, "std_cm": None, "max_abs_cm": None, "rms_cm": None}
            continue
        out[ax] = {
            "mean_cm": float(e.mean()),
            "std_cm": float(e.std(ddof=1)) if len(e) > 1 else 0.0,
            "max_abs_cm": float(np.abs(e).max()),
            "rms_cm": float(np.sqrt((e**2).mean())),
        }
    return out


def markdown_table(axes: dict, n: int, n_found: int, n_truth: int, title: str, split: str) -> str:
    """The thesis-style Markdown table of :func:`error_table`'s result."""

    def f(v):
        return "–" if v is None else f"{v:.3f}"

    lines = [
        f"### {title}",
        "",
        f"split: {split}; pairs: {n}; found: {n_found}; evaluated (found, with truth): {n_truth}",
        "",
        "| axis | mean error (cm) | std (cm) | max abs (cm) | RMS (cm) |",
        "|---|---:|---:|---:|---:|",
    ]
    for ax in AXES:
        s = axes[ax]
        lines.append(
            f"| {ax} | {f(s['mean_cm'])} | {f(s['std_cm'])} | {f(s['max_abs_cm'])} | "
            f"{f(s['rms_cm'])} |"
        )
    return "\n".join(lines) + "\n"


def error_figure(measured_cm: np.ndarray, true_cm: np.ndarray, title: str) -> np.ndarray:
    """Histograms of the per-axis errors and error vs distance (2 x 2 panels), as a BGR uint8 image.

    720 px wide, the width report.html shows a figure at, so its text stays legible there; the
    axes differ in marker as well as colour in the error-vs-distance panel.
    """
    from nodes.contracts.drawing import figure_bgr, new_figure

    err = np.asarray(measured_cm, float) - np.asarray(true_cm, float)
    dist = np.linalg.norm(np.asarray(true_cm, float), axis=1) if len(err) else np.zeros(0)
    fig = new_figure(8.0, 6.2)
    # one layout pass (a plain 2 x 2 grid: nothing constrained layout would place better), 0.55 ->
    # 0.38 s; rect=None: the engine's default rect (0, 0, 1, 1), the whole figure too, makes
    # matplotlib measure every label twice for the same margins (same pixels, ~0.1 s less at the end
    # of every run)
    fig.set_layout_engine("tight", rect=None)
    colours, markers = ("C0", "C1", "C2"), ("o", "s", "^")
    for i, ax_name in enumerate(AXES):
        ax = fig.add_subplot(2, 2, i + 1)
        if len(err):
            # one filled outline, not a rectangle per bin: looks the same, draws and lays out faster
            ax.hist(
                err[:, i],
                bins=max(5, min(30, len(err) // 3)),
                color=colours[i],
                histtype="stepfilled",
            )
        ax.set_xlabel(f"{ax_name} error, measured − truth (cm)")
        ax.set_ylabel("pairs")
        # (matplotlib's default crowded '−0.075−0.050' into each other)
        ax.locator_params(axis="x", nbins=5)
    ax = fig.add_subplot(2, 2, 4)
    for i, ax_name in enumerate(AXES):
        if len(err):
            ax.plot(
                dist,
                err[:, i],
                markers[i],
                ms=4,
                mfc="none" if i else colours[i],
                label=ax_name,
                color=colours[i],
            )
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("distance to the camera (cm)")
    ax.set_ylabel("error, measured − truth (cm)")
    if len(err):
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no found pair with truth", transform=ax.transAxes, ha="center")
    fig.suptitle(f"{title} ({len(err)} pairs)", fontsize=11)
    return figure_bgr(fig)


def location_records(locations: dict) -> list[dict]:
    """The ``locations.json`` records, one per pair, ordered by pair id."""
    keys = (
        "pair",
        "found",
        "reason",
        "x_cm",
        "y_cm",
        "z_cm",
        "sigma_z_cm",
        "frame",
        "split",
        "truth_cm",
        "disparity_px",
        "method",
        "color_from",
    )
    out = []
    for item, loc in locations.items():
        rec = {k: loc.get(k) for k in keys}
        rec["pair"] = rec["pair"] or item
        rec.update(raw_location_fields(loc))
        out.append(rec)
    return out


def raw_location_fields(loc: dict) -> dict:
    """``extrapolated`` and the raw (uncompensated) ``raw_x_cm``, ``raw_y_cm``, ``raw_z_cm`` of a
    Location.

    A compensated location keeps what the locator measured in ``compensation.raw_cm``; an
    uncompensated one's raw values are its own. Written next to the corrected values so that a
    person can see what the correction did to each pair.
    """
    raw = (loc.get("compensation") or {}).get("raw_cm")
    if raw is None:
        raw = [loc.get("x_cm"), loc.get("y_cm"), loc.get("z_cm")]
    return {
        "extrapolated": bool(loc.get("extrapolated", False)),
        "raw_x_cm": raw[0],
        "raw_y_cm": raw[1],
        "raw_z_cm": raw[2],
    }


@node(
    "report.accuracy",
    inputs={
        "locations": In("Location", gather=True, description="All located pairs (with truth).")
    },
    outputs={
        "report": Out(
            "AccuracyReport",
            save=True,
            headline=True,
            description="Per-axis error statistics (cm).",
        ),
        "locations": Out(
            "any", save=True, description="One record per pair: found, x/y/z, sigma_z, frame."
        ),
        "figure": Out(
            "Image",
            save=True,
            headline=True,
            description="Error histograms and error vs distance (cm).",
        ),
        "metrics": Out(
            "Metrics",
            save=True,
            optional=True,
            description="Counts, found rate and per-axis mean/std/RMS/max |error| (cm), flat.",
        ),
        "accuracy": Out(
            "TextFile",
            save=True,
            optional=True,
            description="The table as Markdown (accuracy.md), thesis-style.",
        ),
    },
    params=AccuracyParams,
    version="3",
    prepare=load_figures,
)
def accuracy(params: AccuracyParams, locations, ctx=None):
    """Per-axis error table (mean, std, max |err|, RMS in cm) of the located pairs against truth."""
    if not isinstance(locations, dict):
        raise NodeError(
            "report.accuracy expects the gathered Location items ({pair: Location}).",
            hint="wire `locations` to locator.triangulate's `location` output.",
        )
    sel = _in_split(params, locations, ctx)
    found = [v for v in sel.values() if v.get("found")]
    with_truth = [v for v in found if v.get("truth_cm") is not None and v.get("x_cm") is not None]
    meas = np.array([[v["x_cm"], v["y_cm"], v["z_cm"]] for v in with_truth], float).reshape(-1, 3)
    true = np.array([v["truth_cm"] for v in with_truth], float).reshape(-1, 3)
    axes = error_table(meas, true)
    frames = sorted({v.get("frame") for v in with_truth if v.get("frame")})
    md = markdown_table(axes, len(sel), len(found), len(with_truth), params.title, params.split)
    reasons, kinds, md = _not_found(sel, len(found), md)
    # Pairs that failed before reaching this report (a node's error, not a "not found") are not in
    # `n`: their split is unknown here. Said, so that fewer pairs never look like a better method.
    lost = (ctx.lost.get("locations", {}) if ctx is not None else {}) or {}
    if lost:
        md = _noted(md, _lost_note(lost), ctx)
    report = {
        "n": len(sel),
        "n_found": len(found),
        "n_evaluated": len(with_truth),
        "split": params.split,
        "frame": frames[0] if len(frames) == 1 else frames,
        "axes": axes,
        "markdown": md,
        "not_found_reasons": reasons,
        "not_found_kinds": [{"reason": t, "count": n} for t, n in kinds],
        "n_lost": len(lost),
        "lost": lost,
    }
    fig = error_figure(meas, true, params.title) if params.figure else None  # off: no file
    n_extrapolated = sum(bool(v.get("extrapolated")) for v in with_truth)
    # corrected outside the range the compensation was fitted on: said where people read
    if n_extrapolated:
        note = (
            f"{n_extrapolated} of the {len(with_truth)} evaluated results were corrected "
            "outside the range the "
            "compensation was fitted on (`extrapolated` in locations.json)."
        )
        report["markdown"] = md = _noted(md, note, ctx)
    # (an output, so that a cached report's run folder gets it too, and a later run clears it)
    return {
        "report": report,
        "locations": location_records(locations),
        "figure": fig,
        "metrics": {
            **accuracy_metrics(axes, len(sel), len(found), len(with_truth), n_extrapolated),
            "n_lost": len(lost),
            **(kind_metrics(sel) if params.by_kind else {}),
        },
        "accuracy": {"file_text": md, "file_suffix": ".md"},
    }


def _lost_note(lost: dict[str, str]) -> str:
    """What the report says of the pairs that failed before reaching it."""
    first = next(iter(lost.items()))
    return (
        f"{len(lost)} pair(s) failed before reaching this report and are not counted "
        "here (first: "
        f"{first[0]}: {first[1]}); `lost` in report.json lists each."
    )


def _noted(md: str, note: str, ctx) -> str:
    """``md`` with ``note`` as a paragraph of its own, which the run's messages show too."""
    if ctx is not None:
        ctx.warn(note)
    return f"{md.rstrip()}\n\n{note}\n"


def _in_split(params: AccuracyParams, locations: dict, ctx) -> dict:
    """The locations of the report's split (all of them when none carries one), warning when
    that leaves none."""
    sel = {
        k: v
        for k, v in locations.items()
        if isinstance(v, dict) and (params.split == "all" or v.get("split") in (params.split, None))
    }
    if (
        params.split != "all"
        and sel
        and all(v.get("split") is None for v in sel.values())
        and ctx is not None
    ):
        ctx.warn("no item carries a `split`; all items evaluated")
    if not sel and locations and ctx is not None:
        ctx.warn(
            f"none of the {len(locations)} locations is in the '{params.split}' split: "
            "the report is empty "
            f"(set `split: all`, or leave some placements for {params.split})"
        )
    return sel


def _not_found(sel: dict, n_found: int, md: str) -> tuple[dict[str, int], list, str]:
    """``(count per reason, kinds of reason with counts, md with a "Not found" section)`` of the
    pairs in ``sel`` that were not found."""
    reasons: dict[str, int] = {}
    for v in sel.values():
        if not v.get("found"):
            r = str(v.get("reason") or "unknown")
            reasons[r] = reasons.get(r, 0) + 1
    # one line per kind of reason (its numbers as ranges), where people read: a cause every pair
    # shares (swapped images, another rig's calibration) shows as one line with its count
    kinds = group_reasons(reasons)
    if kinds:
        shown = [f"- {n} × {text}" for text, n in kinds[:MAX_REASON_LINES]]
        more = sum(n for _, n in kinds[MAX_REASON_LINES:])
        md = (
            f"{md.rstrip()}\n\nNot found ({len(sel) - n_found} pairs):\n\n"
            + "\n".join(shown)
            + (
                f"\n- {more} × other kinds of reason (`not_found_kinds` in report.json)"
                if more
                else ""
            )
            + "\n"
        )
    return reasons, kinds, md


def kind_metrics(locations: dict[str, dict]) -> dict[str, float | int]:
    """Per kind of pair (the id less its trailing digits): ``found_<kind>`` (the found rate) and
    ``off_1cm_<kind>`` (found with truth, more than 1 cm from it: the wrong answers)."""
    out: dict[str, float | int] = {}
    groups: dict[str, list[dict]] = {}
    for pid, v in locations.items():
        groups.setdefault(re.sub(r"\d+$", "", str(pid)) or "pair", []).append(v)
    for kind, vs in sorted(groups.items()):
        found = [v for v in vs if v.get("found")]
        off = [
            v
            for v in found
            if v.get("truth_cm") is not None
            and v.get("x_cm") is not None
            and np.linalg.norm(np.subtract([v["x_cm"], v["y_cm"], v["z_cm"]], v["truth_cm"])) > 1.0
        ]
        out[f"found_{kind}"] = len(found) / len(vs)
        out[f"off_1cm_{kind}"] = len(off)
    return out


def accuracy_metrics(axes: dict, n: int, n_found: int, n_truth: int, n_extrapolated: int) -> dict:
    """The report as flat ``Metrics`` (what ``stereograph compare`` tabulates).

    Parameters
    ----------
    axes : dict
        :func:`error_table`'s result.
    n, n_found, n_truth, n_extrapolated : int
        Items in the split; found; found with truth (evaluated); of those, corrected outside the
        range a compensation model was fitted on.

    Returns
    -------
    dict
        ``{"n", "n_found", "found_rate" (found / n, None for n = 0), "n_truth", "n_extrapolated",
        "x_mean_cm", "x_std_cm", "x_rms_cm", "x_max_abs_cm", "y_...", "z_..."}``.
    """
    out = {
        "n": n,
        "n_found": n_found,
        "found_rate": n_found / n if n else None,
        "n_truth": n_truth,
        "n_extrapolated": n_extrapolated,
    }
    for ax in AXES:
        for stat in ("mean_cm", "std_cm", "rms_cm", "max_abs_cm"):
            out[f"{ax}_{stat}"] = axes[ax][stat]
    return out
