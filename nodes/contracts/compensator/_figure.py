"""The picture of a compensation fit: the correction over the training placements it was fitted on.

Every compensator fit node saves one (``fit/figure.png``, shown in ``report.html``). It answers
what a person asks before trusting a correction: does the curve follow the placements, where was
it fitted (the *valid range*, outside which ``compensator.apply`` flags ``extrapolated: true``),
which placements were left out as mis-detections, and do the test placements agree.

The picture is computed in two steps so that its content can be tested without looking at pixels:
:func:`fit_picture` gathers the numbers (a :class:`FitPicture`), :func:`draw` renders them with
matplotlib (Agg, imported only there).

What is drawn, per corrected axis (one panel each; depth-only models have the z panel only):

- x: the model's own depth variable, measured z (cm) or disparity d (px);
- y: the error the correction removes, ``truth - measured`` (cm), per placement;
- the correction along one *reference ray*, as a line: the model's prediction for measurements
  at the training placements' typical image position for each depth (u, v fitted as straight
  lines of d) with ``z d`` equal to the training median. For a model of z alone this is the model
  itself; for a model that also reads u, v (``compensator.xyz``) or whose correction depends on
  the ray (``compensator.disparity_curve`` in rectified depth) it is one slice, so the model's
  value *at each training placement* is drawn too, as small marks.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nodes.contracts.compensator._common import Samples, model_metrics, samples_from_locations

__all__ = ["FitPicture", "Panel", "draw", "fit_figure", "fit_picture", "held_out"]

AXES = ("x", "y", "z")
# : The curve is drawn this far (fraction of the valid span) beyond each end of the valid range,
# dashed.
MARGIN_FRACTION = 0.08
GRID_POINTS = 300
#: Outliers named on the picture at most (the model lists them all).
MAX_LABELLED = 8

_X_LABEL = {
    "z_cm": "measured distance z (cm)",
    "disparity_px": "measured disparity d (px)  —  larger is nearer",
}


@dataclass
class Panel:
    """One corrected axis: errors (truth - measured, cm) of each group of placements, and the
    model."""

    axis: str
    train_y: np.ndarray
    outlier_y: np.ndarray
    test_y: np.ndarray
    curve_y: np.ndarray
    #: The model's correction at each training placement (cm); None where it equals the curve there.
    fitted_y: np.ndarray | None = None


@dataclass
class FitPicture:
    """The numbers of a compensation figure (x in the unit of ``variable``)."""

    title: str
    formula: str
    variable: str
    train_x: np.ndarray
    outlier_x: np.ndarray
    outlier_labels: list[str]
    test_x: np.ndarray
    grid_x: np.ndarray
    #: (min, max) of ``variable`` over the placements fitted; None for a model with no valid range.
    valid: tuple[float, float] | None
    panels: list[Panel] = field(default_factory=list)
    note: str = ""


def held_out(collection: Mapping[str, Mapping[str, Any]], needs: tuple[str, ...]) -> Samples | None:
    """The placements a fit did not use but can be judged by: not split 'train', found, with truth.

    Returns None when there are none (a collection with a train split only, or no truth).
    """
    keep = {}
    for item, loc in (collection or {}).items():
        if loc.get("split") == "train" or not loc.get("found") or loc.get("truth_cm") is None:
            continue
        values = [loc.get(k) for k in ("x_cm", "y_cm", "z_cm", *needs)] + list(loc["truth_cm"])[:3]
        if all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            keep[item] = loc
    return samples_from_locations(keep) if keep else None


def _typical(d: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``values`` (an image coordinate) as a straight line of disparity ``d``, evaluated ``at``.

    Balls on a table seen from above: their image row is a straight line of their disparity
    (v - cy = f Y / z = (Y / B) d for a constant height Y), so the line keeps the reference ray
    where the placements are; a plain median would leave that surface, where a model of
    (u, v, d) was never constrained.
    """
    ok = np.isfinite(d) & np.isfinite(values)
    if not np.any(ok):
        return np.full(len(at), math.nan)
    if np.count_nonzero(ok) < 3 or np.ptp(d[ok]) <= 0:
        return np.full(len(at), float(np.median(values[ok])))
    slope, icept = np.polyfit(d[ok], values[ok], 1)
    return slope * at + icept


def _reference(inliers: Samples, variable: str, grid: np.ndarray) -> Samples:
    """Measurements along the reference ray at the grid values of ``variable``.

    z d is held at its training median (K), so ``z = K / d`` and, for the disparity curve in
    rectified depth, the ray factor is 1; u and v follow the training placements (:func:`_typical`).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        zd = inliers.xyz_cm[:, 2] * inliers.disparity_px
        k = float(np.nanmedian(zd)) if np.any(np.isfinite(zd)) else math.nan
        z = grid if variable == "z_cm" else k / grid
        d = k / grid if variable == "z_cm" else grid
    n = len(grid)
    u = _typical(inliers.disparity_px, inliers.u_px, d)
    v = _typical(inliers.disparity_px, inliers.v_px, d)
    return Samples(
        ids=[f"ref{i}" for i in range(n)],
        xyz_cm=np.column_stack([np.zeros(n), np.zeros(n), z]),
        disparity_px=d,
        u_px=u,
        v_px=v,
        truth_cm=None,
        frame=inliers.frame,
    )


def _grid(values: np.ndarray, valid: tuple[float, float] | None, variable: str) -> np.ndarray:
    lo, hi = valid if valid is not None else (float(np.min(values)), float(np.max(values)))
    pad = MARGIN_FRACTION * (hi - lo)
    a, b = lo - pad, hi + pad
    if variable == "disparity_px":
        a = max(a, 0.5 * lo)  # a disparity stays positive (the curve's pole lies left of the data)
    return np.linspace(a, b, GRID_POINTS)


def fit_picture(
    model: Mapping[str, Any],
    candidates: Samples,
    predict: Callable[[Mapping[str, Any], Samples], np.ndarray],
    test: Samples | None = None,
    variable: str = "z_cm",
    axes: tuple[str, ...] = ("z",),
    formula: str = "",
) -> FitPicture:
    """The numbers of a fit's figure.

    Parameters
    ----------
    model : dict
        The ``CompensationModel`` the fit node built (``coefficients``, ``valid_range``,
        ``outliers``).
    candidates : Samples
        Every training placement the fit considered, outliers included (cm, px).
    predict : callable
        The model's ``predict(coefficients, samples) -> xyz (N, 3) cm``.
    test : Samples, optional
        Held-out placements with truth, drawn for comparison (not fitted).
    variable : {"z_cm", "disparity_px"}
        The x axis: the model's depth variable.
    axes : tuple of str
        The corrected axes, one panel each.
    formula : str
        One line saying what was fitted (shown under the title).
    """
    inliers, outliers, labels = _inliers_and_outliers(model, candidates)
    rng = (model.get("valid_range") or {}).get(variable)
    valid = (float(rng["min"]), float(rng["max"])) if rng else None
    train_x = inliers.variable(variable) if len(inliers) else np.zeros(0)
    grid = _grid(train_x, valid, variable) if len(train_x) else np.zeros(0)
    coefficients = model.get("coefficients") or {}
    ref = _reference(inliers, variable, grid) if len(grid) else None
    ref_correction = (
        (np.asarray(predict(coefficients, ref), float) - ref.xyz_cm) if ref is not None else None
    )
    fitted_all = (
        (np.asarray(predict(coefficients, inliers), float) - inliers.xyz_cm)
        if len(inliers)
        else None
    )
    panels = [
        _panel(name, inliers, outliers, test, train_x, grid, ref_correction, fitted_all)
        for name in axes
    ]
    cv = model_metrics(model).get("cv_z_rms_cm")
    title = (
        f"compensator.{model.get('type', '?')}: n_train = {len(inliers)}, outliers left "
        f"out = {len(outliers)}, "
        f"CV z RMS = {'n/a' if cv is None else f'{cv:.3g} cm'}"
    )
    note = ""
    if any(p.fitted_y is not None for p in panels):
        note = (
            "line: the model at the training placements' typical image position (u, v) "
            "for each depth; "
            "orange dashes: the model at each training placement"
        )
    return FitPicture(
        title=title,
        formula=formula,
        variable=variable,
        train_x=train_x,
        outlier_x=outliers.variable(variable) if len(outliers) else np.zeros(0),
        outlier_labels=labels,
        test_x=test.variable(variable) if test is not None else np.zeros(0),
        grid_x=grid,
        valid=valid,
        panels=panels,
        note=note,
    )


def _inliers_and_outliers(
    model: Mapping[str, Any], candidates: Samples
) -> tuple[Samples, Samples, list[str]]:
    """``(the placements fitted, those left out (largest residual first), their labels)``."""
    out_ids = [str(o["item"]) for o in model.get("outliers") or []]
    is_out = np.array([i in set(out_ids) for i in candidates.ids], dtype=bool)
    # the model lists them largest residual first
    rank = {item: r for r, item in enumerate(out_ids)}
    out_idx = sorted(np.flatnonzero(is_out), key=lambda i: rank[candidates.ids[i]])
    inliers = candidates.subset(np.flatnonzero(~is_out))
    outliers = candidates.subset(np.asarray(out_idx, dtype=int))
    residual = {str(o["item"]): o.get("residual_cm") for o in model.get("outliers") or []}
    labels = [
        f"{i} ({residual[i]:.3g} cm from the model)" if residual.get(i) is not None else i
        for i in outliers.ids
    ]
    return inliers, outliers, labels


def _panel(
    name: str,
    inliers: Samples,
    outliers: Samples,
    test: Samples | None,
    train_x: np.ndarray,
    grid: np.ndarray,
    ref_correction: np.ndarray | None,
    fitted_all: np.ndarray | None,
) -> Panel:
    """One corrected axis's panel: errors (truth - measured) of each set of placements, the
    model's correction along ``grid``, and its value at each training placement (None when the
    curve already shows it)."""
    k = AXES.index(name)

    def err(s: Samples | None, k: int = k) -> np.ndarray:
        return np.zeros(0) if s is None or len(s) == 0 else s.truth_cm[:, k] - s.xyz_cm[:, k]

    curve = ref_correction[:, k] if ref_correction is not None else np.zeros(0)
    fitted = fitted_all[:, k] if fitted_all is not None else None
    if fitted is not None and len(grid):
        on_curve = np.interp(train_x, grid, curve)
        tol = 0.01 * max(float(np.ptp(err(inliers))), 1e-6)
        if np.all(np.abs(on_curve - fitted) <= tol):
            fitted = None  # the curve is the model itself: the marks would repeat it
    return Panel(
        axis=name,
        train_y=err(inliers),
        outlier_y=err(outliers),
        test_y=err(test),
        curve_y=curve,
        fitted_y=fitted,
    )


def _limits(p: Panel, pic: FitPicture) -> tuple[float, float]:
    """y limits that show the fitted placements and the model; far-off points are drawn at the edge.

    Where the line is only a slice of the model (``fitted_y`` set), the placements and the model's
    values at them set the scale, and the line may leave the plot (:func:`draw` says so).
    """
    inside = pic.valid is None or len(pic.grid_x) == 0
    sel = (
        np.ones(len(pic.grid_x), bool)
        if inside
        else (pic.grid_x >= pic.valid[0]) & (pic.grid_x <= pic.valid[1])
    )
    line = p.curve_y[sel] if p.fitted_y is None else np.zeros(0)
    core = np.concatenate([p.train_y, line, p.fitted_y if p.fitted_y is not None else np.zeros(0)])
    core = core[np.isfinite(core)]
    if not len(core):
        core = np.array([-1.0, 1.0])
    lo, hi = float(np.min(core)), float(np.max(core))
    span = max(hi - lo, 1e-3)
    # test placements near the fit count too
    near = p.test_y[(p.test_y > lo - span) & (p.test_y < hi + span)]
    if p.fitted_y is not None:  # the slice too, where it stays near the placements
        curve = p.curve_y[sel]
        near = np.concatenate(
            [near, curve[np.isfinite(curve) & (curve > lo - span) & (curve < hi + span)]]
        )
    if len(near):
        lo, hi = min(lo, float(np.min(near))), max(hi, float(np.max(near)))
        span = max(hi - lo, 1e-3)
    return lo - 0.12 * span, hi + 0.12 * span


def _outlier_list(pic: FitPicture) -> str | None:
    """The numbered outliers, named under the plot (labels on the plot would overlap)."""
    if not pic.outlier_labels:
        return None
    shown = [f"{j + 1}: {text}" for j, text in enumerate(pic.outlier_labels[:MAX_LABELLED])]
    more = len(pic.outlier_labels) - MAX_LABELLED
    lines = textwrap.wrap(
        "left out: " + ",  ".join(shown) + (f",  +{more} more (model.json)" if more > 0 else ""),
        115,
    )
    return "\n".join(lines)


def draw(pic: FitPicture) -> np.ndarray:
    """Render a :class:`FitPicture` as a BGR uint8 image (matplotlib, Agg)."""
    from nodes.contracts.drawing import figure_bgr, new_figure

    n = max(1, len(pic.panels))
    fig = new_figure(8.0, 1.7 + 3.0 * n)  # 720 px wide: report.html shows it unscaled
    fig.set_layout_engine("constrained")
    legend_handles: dict[str, Any] = {}
    axes = []
    for k, p in enumerate(pic.panels):
        ax = fig.add_subplot(n, 1, k + 1, sharex=axes[0] if axes else None)
        axes.append(ax)
        _draw_panel(ax, p, pic, legend_handles)
    if axes:
        axes[-1].set_xlabel(_X_LABEL.get(pic.variable, pic.variable), fontsize=9)
    order = ["valid", "curve", "extra", "fitted", "train", "outlier", "test"]
    handles = [legend_handles[key] for key in order if key in legend_handles]
    if handles:
        fig.legend(
            handles=handles,
            labels=[h.get_label() for h in handles],
            loc="outside lower center",
            ncol=min(3, len(handles)),
            fontsize=8,
            frameon=False,
            title=_outlier_list(pic),
            title_fontsize=8,
        )
    head = "\n".join(textwrap.fill(t, 95) for t in (pic.title, pic.formula, pic.note) if t)
    fig.suptitle(head, fontsize=10)
    return figure_bgr(fig)


def _draw_panel(ax: Any, p: Panel, pic: FitPicture, legend_handles: dict[str, Any]) -> None:
    """One axis's panel: the valid range, the fitted curve, the placements, the notes."""
    lo, hi = _limits(p, pic)
    if pic.valid is not None:
        h = ax.axvspan(*pic.valid, color="#d5efd5", zorder=0, label="valid range (span fitted)")
        legend_handles.setdefault("valid", h)
    ax.axhline(0.0, color="#888", lw=0.7, zorder=1)
    _draw_curve(ax, p, pic, legend_handles)
    _draw_placements(ax, p, pic, lo, hi, legend_handles)
    ax.set_ylim(lo, hi)
    _note_off_scale(ax, p, pic, lo, hi)
    ax.set_ylabel(f"{p.axis} error, truth − measured (cm)", fontsize=9)
    ax.grid(True, lw=0.4, alpha=0.5)
    if not len(p.train_y) and not len(p.outlier_y):
        ax.text(
            0.5,
            0.5,
            "no training placements: nothing was fitted",
            transform=ax.transAxes,
            ha="center",
            va="center",
            fontsize=11,
        )


def _draw_curve(ax: Any, p: Panel, pic: FitPicture, legend_handles: dict[str, Any]) -> None:
    """The fitted correction over the grid: solid in the valid range, dashed beyond it."""
    if len(pic.grid_x):
        inside = (
            np.ones(len(pic.grid_x), bool)
            if pic.valid is None
            else (pic.grid_x >= pic.valid[0]) & (pic.grid_x <= pic.valid[1])
        )
        (h,) = ax.plot(
            pic.grid_x,
            np.where(inside, p.curve_y, np.nan),
            "-",
            color="k",
            lw=2,
            zorder=4,
            label="fitted correction",
        )
        legend_handles.setdefault("curve", h)
        if pic.valid is not None:
            (h,) = ax.plot(
                pic.grid_x,
                np.where(inside, np.nan, p.curve_y),
                "--",
                color="k",
                lw=1.3,
                zorder=4,
                label="extrapolated (flagged by apply)",
            )
            legend_handles.setdefault("extra", h)


def _draw_placements(
    ax: Any, p: Panel, pic: FitPicture, lo: float, hi: float, legend_handles: dict[str, Any]
) -> None:
    """Test, fitted and training placements, and the outliers left out (numbered)."""
    if len(p.test_y):
        y = np.clip(p.test_y, lo, hi)
        h = ax.scatter(
            pic.test_x,
            y,
            marker="s",
            s=22,
            facecolors="none",
            edgecolors="#7f7f7f",
            lw=1,
            zorder=3,
            label="test placements (not fitted)",
        )
        legend_handles.setdefault("test", h)
    if p.fitted_y is not None:
        h = ax.scatter(
            pic.train_x,
            p.fitted_y,
            marker="_",
            s=60,
            color="#e67e22",
            lw=1.5,
            zorder=5,
            label="model at each training placement",
        )
        legend_handles.setdefault("fitted", h)
    if len(p.train_y):
        h = ax.scatter(
            pic.train_x,
            p.train_y,
            marker="o",
            s=16,
            color="#1f77b4",
            zorder=6,
            label="training placements (fitted)",
        )
        legend_handles.setdefault("train", h)
    if len(p.outlier_y):
        _draw_outliers(ax, p, pic, lo, hi, legend_handles)


def _draw_outliers(
    ax: Any, p: Panel, pic: FitPicture, lo: float, hi: float, legend_handles: dict[str, Any]
) -> None:
    """The placements left out of the fit, numbered (those off the scale on its edge)."""
    y = np.clip(p.outlier_y, lo, hi)  # far off the scale: drawn at the axis edge
    h = ax.scatter(
        pic.outlier_x,
        y,
        marker="X",
        s=70,
        color="#d62728",
        edgecolors="k",
        lw=0.5,
        zorder=7,
        label="left out of the fit (on the edge: off the scale)",
    )
    legend_handles.setdefault("outlier", h)
    for j, (x0, y0) in enumerate(zip(pic.outlier_x[:MAX_LABELLED], y[:MAX_LABELLED])):
        ax.annotate(
            str(j + 1),
            (x0, y0),
            xytext=(5 if j % 2 == 0 else -12, -11 if y0 >= (lo + hi) / 2 else 4),
            textcoords="offset points",
            fontsize=8,
            fontweight="bold",
            color="#a11",
        )


def _note_off_scale(ax: Any, p: Panel, pic: FitPicture, lo: float, hi: float) -> None:
    """Say so when the fitted line leaves the plot inside the valid range."""
    if p.fitted_y is not None and len(pic.grid_x):
        in_range = pic.valid is None or len(pic.grid_x) == 0
        sel = True if in_range else (pic.grid_x >= pic.valid[0]) & (pic.grid_x <= pic.valid[1])
        c = p.curve_y[np.isfinite(p.curve_y) & sel]
        if len(c) and (np.min(c) < lo or np.max(c) > hi):
            ax.text(
                0.01,
                0.97,
                f"the line leaves the plot inside the valid range: {np.min(c):+.3g} to "
                f"{np.max(c):+.3g} cm (between placements the model is unconstrained)",
                transform=ax.transAxes,
                va="top",
                fontsize=7.5,
                color="#333",
                bbox={"fc": "white", "ec": "#bbb", "alpha": 0.85},
            )


def fit_figure(
    model: Mapping[str, Any],
    candidates: Samples,
    predict: Callable[[Mapping[str, Any], Samples], np.ndarray],
    test: Samples | None = None,
    variable: str = "z_cm",
    axes: tuple[str, ...] = ("z",),
    formula: str = "",
    enabled: bool = True,
) -> np.ndarray:
    """:func:`fit_picture` drawn by :func:`draw`: the BGR image a fit node saves as its ``figure``.

    With ``enabled`` false (the fit's ``figure: false``) a one-line picture says it was not drawn.
    """
    if not enabled:
        from nodes.contracts.drawing import caption

        return caption(np.full((4, 480, 3), 255, np.uint8), ["figure not drawn (figure: false)"])
    return draw(fit_picture(model, candidates, predict, test, variable, axes, formula))
