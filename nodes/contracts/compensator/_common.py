"""Shared pieces of the compensator nodes: training samples, statistics, k-fold CV.

A compensator removes the *systematic* part of the localisation error. It is
fitted on the training split of placements that carry ground truth and applied
to any later measurement. Every model is described by two pure functions,

``fit(samples, **options) -> coefficients`` and
``predict(coefficients, samples) -> corrected xyz (N, 3) in cm``,

plus the names of the measured quantities it reads (``z_cm``, ``disparity_px``,
``u_left_px``, ``v_left_px``), whose training range becomes the model's valid
range. :func:`build_model` wraps a pair into the ``CompensationModel`` artifact
(coefficients, valid range, training residuals, cross-validation, fit time).

Errors are ``measured - truth`` per axis, in cm, everywhere in this package.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, NoReturn

import numpy as np

from nodes.contracts.reasons import group_reasons
from stereograph.api import Field, In, NodeError, Out, Params

__all__ = [
    "TRAIN_INPUT",
    "FitParams",
    "RayFitParams",
    "Samples",
    "along_ray",
    "axis_stats",
    "build_model",
    "kfold_cv",
    "METRICS_OUTPUT",
    "model_metrics",
    "node_label",
    "require_span",
    "resolve_along_ray",
    "samples_from_locations",
    "training_samples",
]

AXES = ("x", "y", "z")
#: Location keys a model may read, in the order of :attr:`Samples.variable`.
VARIABLES = ("x_cm", "y_cm", "z_cm", "disparity_px", "u_left_px", "v_left_px")


class FitParams(Params):
    """Parameters every fitting compensator shares."""

    cv_folds: int = Field(
        5,
        ge=2,
        le=50,
        description="k of the k-fold cross-validation reported with the fit (folds, unitless).",
    )
    cv_seed: int = Field(
        0, ge=0, description="Seed of the shuffle that assigns placements to CV folds (unitless)."
    )
    min_span_fraction: float = Field(
        0.02,
        ge=0.0,
        le=1.0,
        description=(
            "Smallest spread of the training distances, as a fraction of their median (unitless): "
            "placements all at (nearly) one distance cannot define a distance-dependent correction."
        ),
    )
    outlier_mad: float | None = Field(
        5.0,
        gt=0,
        le=100,
        description=(
            "A training placement whose residual against the fitted model (3-D, cm) lies "
            "more than this many "
            "robust standard deviations (1.4826 x median absolute deviation of all "
            "residuals) above their median "
            "is a mis-detection: left out of the fit and listed in the model (unitless; "
            "null keeps every placement)."
        ),
    )
    min_inlier_fraction: float = Field(
        0.5,
        ge=0.5,
        le=1.0,
        description=(
            "Fewest training placements, as a fraction of the usable ones, that must "
            "agree with the fit; fewer and "
            "the fit refuses (unitless; below one half the median no longer describes "
            "the correct placements)."
        ),
    )
    figure: bool = Field(
        True,
        description="Draw the fit's figure (figure.png, shown in report.html: the correction "
        "over the training "
        "placements, the valid range, the outliers); false skips the drawing, about half "
        "a second per fit (bool).",
    )
    max_residual_sigma: float | None = Field(
        20.0,
        gt=1,
        le=1000,
        description=(
            "The fit refuses when the median depth residual of the placements it keeps "
            "exceeds this many times "
            "their median stated depth uncertainty (sigma_z_cm): the training set then "
            "disagrees with itself, as "
            "when most placements are mis-detections (unitless; null skips the check, as "
            "does data without sigma_z_cm)."
        ),
    )


class RayFitParams(FitParams):
    """Fit parameters of the depth-only compensators, which may move x and y along the ray too."""

    xy: Literal["auto", "along_ray", "keep"] = Field(
        "auto",
        description="What a depth correction does to x, y: along_ray rescales them by "
        "z_corrected / z_measured "
        "(errors of baseline or disparity offset move a point along its viewing ray), "
        "keep leaves them "
        "(errors of focal length change z only), auto picks whichever fits the training "
        "x, y better.",
    )


#: The input of every fit node: the gathered Location collection (only split 'train' is used).
TRAIN_INPUT = {
    "train": In(
        "Location", gather=True, description="Located placements; only split 'train' is used."
    )
}

#: The ``Metrics`` output of every fit node (what ``stereograph compare`` tabulates).
METRICS_OUTPUT = {
    "metrics": Out(
        "Metrics",
        save=True,
        optional=True,
        description="fit_time_s, n_train, n_outliers, cv_z_rms_cm (flat).",
    )
}


def model_metrics(model: Mapping[str, Any]) -> dict[str, float | int | None]:
    """A fitted ``CompensationModel`` as flat ``Metrics``.

    Returns
    -------
    dict
        ``{"fit_time_s": s, "n_train": placements fitted, "n_outliers": left out,
        "cv_z_rms_cm": cross-validated z RMS error (cm), None when no cross-validation ran}``.
    """
    cv_z = ((model.get("cv") or {}).get("axes") or {}).get("z") or {}
    return {
        "fit_time_s": model.get("fit_time_s"),
        "n_train": model.get("n_train"),
        "n_outliers": model.get("n_outliers", 0),
        "cv_z_rms_cm": cv_z.get("rms_cm"),
    }


@dataclass(frozen=True)
class Samples:
    """Measured locations (and truth, when known) as arrays.

    Attributes
    ----------
    ids : list of str
        Item ids, in order.
    xyz_cm : ndarray (N, 3)
        Measured position, cm, in ``frame``.
    disparity_px : ndarray (N,)
        Rectified disparity, px (NaN where the locator did not report it).
    u_px, v_px : ndarray (N,)
        Rectified left image position used for x, y, px (NaN where unknown).
    truth_cm : ndarray (N, 3) or None
        Ground-truth position, cm, same frame.
    frame : str
        ``"left_camera"`` or ``"table"``.
    sigma_z_cm : ndarray (N,) or None
        The locator's stated depth uncertainty, cm (NaN where not reported).
    rig : dict or None
        The rig the locations were measured with (``Location["rig"]``: image size, focal length,
        baseline), recorded in the fitted model so that a loader can refuse it on another rig.
    """

    ids: list[str]
    xyz_cm: np.ndarray
    disparity_px: np.ndarray
    u_px: np.ndarray
    v_px: np.ndarray
    truth_cm: np.ndarray | None
    frame: str
    sigma_z_cm: np.ndarray | None = None
    rig: dict | None = None

    def __len__(self) -> int:
        return len(self.ids)

    def variable(self, name: str) -> np.ndarray:
        """One measured quantity by its Location key (``z_cm``, ``disparity_px``, ...)."""
        table = {
            "x_cm": self.xyz_cm[:, 0],
            "y_cm": self.xyz_cm[:, 1],
            "z_cm": self.xyz_cm[:, 2],
            "disparity_px": self.disparity_px,
            "u_left_px": self.u_px,
            "v_left_px": self.v_px,
        }
        return table[name]

    def subset(self, index: np.ndarray) -> Samples:
        index = np.asarray(index)
        return Samples(
            ids=[self.ids[i] for i in index],
            xyz_cm=self.xyz_cm[index],
            disparity_px=self.disparity_px[index],
            u_px=self.u_px[index],
            v_px=self.v_px[index],
            truth_cm=None if self.truth_cm is None else self.truth_cm[index],
            frame=self.frame,
            sigma_z_cm=None if self.sigma_z_cm is None else self.sigma_z_cm[index],
            rig=self.rig,
        )


def node_label(ctx: Any, node_type: str) -> str:
    """``'fit' (compensator.polynomial)`` when the run context is known, else the type."""
    name = getattr(ctx, "node_name", None)
    return f"node '{name}' ({node_type})" if name else f"node {node_type}"


def _num(value: Any) -> float:
    """A Location number as float, NaN for None / missing."""
    if value is None:
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def samples_from_locations(
    locations: Mapping[str, Mapping[str, Any]] | list[Mapping[str, Any]],
) -> Samples:
    """Arrays from Location records (found ones are expected; no filtering here).

    Parameters
    ----------
    locations : mapping item_id -> Location, or list of Location
        Location artifacts (``docs/artifacts.md``).

    Returns
    -------
    Samples
        ``truth_cm`` is None unless every record carries ``truth_cm``.
    """
    items = (
        list(locations.items())
        if isinstance(locations, Mapping)
        else [(str(loc.get("pair", i)), loc) for i, loc in enumerate(locations)]
    )
    n = len(items)
    xyz = np.full((n, 3), np.nan)
    truth = np.full((n, 3), np.nan)
    disp = np.full(n, np.nan)
    u = np.full(n, np.nan)
    v = np.full(n, np.nan)
    sigma_z = np.full(n, np.nan)
    has_truth = n > 0
    frames = set()
    rig = next((loc.get("rig") for _, loc in items if loc.get("rig")), None)
    for i, (_, loc) in enumerate(items):
        xyz[i] = [_num(loc.get("x_cm")), _num(loc.get("y_cm")), _num(loc.get("z_cm"))]
        disp[i] = _num(loc.get("disparity_px"))
        u[i] = _num(loc.get("u_left_px"))
        v[i] = _num(loc.get("v_left_px"))
        sigma_z[i] = _num(loc.get("sigma_z_cm"))
        t = loc.get("truth_cm")
        if t is None:
            has_truth = False
        else:
            truth[i] = [_num(c) for c in list(t)[:3]]
        frames.add(loc.get("frame", "left_camera"))
    if len(frames) > 1:
        raise NodeError(
            f"Location records mix coordinate frames {sorted(frames)}; a compensator "
            "needs one frame."
        )
    return Samples(
        ids=[str(k) for k, _ in items],
        xyz_cm=xyz,
        disparity_px=disp,
        u_px=u,
        v_px=v,
        truth_cm=truth if has_truth else None,
        frame=frames.pop() if frames else "left_camera",
        sigma_z_cm=sigma_z,
        rig=rig,
    )


def training_samples(
    train: Mapping[str, Mapping[str, Any]],
    label: str,
    needs: tuple[str, ...],
    min_points: int,
) -> Samples:
    """The usable training placements of a gathered Location collection.

    Keeps items with ``split == "train"``, ``found`` true, ground truth present
    and every quantity in ``needs`` finite.

    Parameters
    ----------
    train : mapping item_id -> Location
        The gathered collection.
    label : str
        How to name the node in errors (``node 'fit' (compensator.polynomial)``).
    needs : tuple of str
        Location keys the model reads (``"z_cm"``, ``"disparity_px"`` ...).
    min_points : int
        Fewest usable placements the model can be fitted from (its number of
        coefficients, at least).

    Raises
    ------
    NodeError
        When fewer than ``min_points`` placements remain; the message says how
        many items were dropped for which reason.
    """
    if not isinstance(train, Mapping):
        raise NodeError(
            f"{label}: input 'train' must be the gathered Location collection, got "
            f"{type(train).__name__}."
        )
    dropped = {
        "not in the train split": 0,
        "not found": 0,
        "no ground truth": 0,
        "non-finite values": 0,
    }
    reasons: dict[str, int] = {}  # why the training placements were not found
    keep: dict[str, Mapping[str, Any]] = {}
    for item_id, loc in train.items():
        if loc.get("split") != "train":
            dropped["not in the train split"] += 1
            continue
        if not loc.get("found"):
            dropped["not found"] += 1
            reason = str(loc.get("reason") or "no reason given")
            reasons[reason] = reasons.get(reason, 0) + 1
            continue
        truth = loc.get("truth_cm")
        if truth is None:
            dropped["no ground truth"] += 1
            continue
        values = [_num(loc.get(k)) for k in ("x_cm", "y_cm", "z_cm", *needs)] + [
            _num(t) for t in truth
        ]
        if not all(math.isfinite(x) for x in values):
            dropped["non-finite values"] += 1
            continue
        keep[item_id] = loc
    if len(keep) < min_points:
        _refuse_too_few(label, train, keep, dropped, reasons, needs, min_points)
    return samples_from_locations(keep)


def _refuse_too_few(
    label: str,
    train: Mapping[str, Any],
    keep: dict,
    dropped: dict[str, int],
    reasons: dict[str, int],
    needs: tuple[str, ...],
    min_points: int,
) -> NoReturn:
    """Too few usable training placements: say how many were dropped for which reason, and the
    likeliest fix (upstream, when most were not located or carry no truth)."""
    why = (
        ", ".join(f"{n} {reason}" for reason, n in dropped.items() if n)
        or "the collection is empty"
    )
    hint = (
        "use a source with ground truth and more training placements (e.g. "
        "source.synthetic n_scenes / "
        "train_fraction), or a compensator with fewer coefficients (lower degree / fewer bins)."
    )
    in_split = len(train) - dropped["not in the train split"]
    # the locator's own words: a cause shared by every pair (swapped images ...) shows here
    if reasons:
        top, n_top = group_reasons(reasons)[0]
        why += f"; not found, most often ({n_top} of {dropped['not found']}): {top}"
        # the cause is upstream: more placements would not help
        if 2 * dropped["not found"] >= in_split:
            hint = (
                f"most training placements were not located ({dropped['not found']} "
                f"of {in_split}), most "
                f"often because: {top}. Fix that first: the object's declared colour "
                "and radius, or the "
                "segmenter's settings (look at the segment overlays in the run "
                "folder); then run again."
            )
    elif dropped["no ground truth"] and 2 * dropped["no ground truth"] >= in_split:
        hint = (
            "the training placements carry no ground truth (truth_cm): give the "
            "source a truth file, or "
            "use source.synthetic, whose placements know where the ball is."
        )
    raise NodeError(
        f"{label}: only {len(keep)} usable training placements of {len(train)} items ({why}); "
        f"this model needs at least {min_points} (found, with truth_cm, split "
        f"'train', finite {', '.join(needs)}).",
        hint=hint,
    )


def require_span(values: np.ndarray, name: str, label: str, min_fraction: float, unit: str) -> None:
    """Refuse training data whose ``values`` all lie at (nearly) one value.

    The spread (max - min) must reach ``min_fraction`` of the median magnitude:
    a correction that depends on distance cannot be learnt from one distance.
    """
    span = float(np.ptp(values))
    scale = float(np.median(np.abs(values)))
    if not span > max(min_fraction * scale, 1e-9 * max(scale, 1.0)):
        raise NodeError(
            f"{label}: the training placements all lie at one {name} "
            f"({np.min(values):.4g}-{np.max(values):.4g} {unit}, "
            f"spread {span:.3g} {unit} < {min_fraction:.0%} of {scale:.4g} {unit}); a "
            "distance-dependent "
            "correction cannot be fitted from them.",
            hint="place the training objects over the working range of distances, or lower "
            "min_span_fraction.",
        )


def along_ray(
    xyz_cm: np.ndarray, z_new_cm: np.ndarray, frame: str, enabled: bool = True
) -> np.ndarray:
    """Move measured points to a corrected depth.

    In the left-camera frame a measured point lies on the viewing ray through
    the camera centre, and a depth error moves it along that ray, so x and y
    scale with z (x = (u - cx) z / f). Correcting z therefore also rescales x
    and y by ``z_new / z``. In the table frame z is a height, not a depth, and
    only z is replaced.

    Parameters
    ----------
    xyz_cm : ndarray (N, 3)
        Measured points, cm.
    z_new_cm : ndarray (N,)
        Corrected depths, cm.
    frame : str
        ``"left_camera"`` or ``"table"``.
    enabled : bool
        False replaces z only.
    """
    out = np.array(xyz_cm, dtype=float, copy=True)
    z_new = np.asarray(z_new_cm, dtype=float)
    if enabled and frame == "left_camera":
        scale = z_new / out[:, 2]
        out[:, 0] *= scale
        out[:, 1] *= scale
    out[:, 2] = z_new
    return out


def resolve_along_ray(mode: str, samples: Samples, z_new_cm: np.ndarray) -> bool:
    """Decide whether a depth correction also rescales x, y along the ray.

    ``"auto"`` compares, on the training placements, the x/y residual sum of squares of
    moving along the ray against keeping x, y as measured, and picks the smaller (one binary
    choice, so fitting it on the training data does not overfit).
    """
    if samples.frame != "left_camera" or mode == "keep":
        return False
    if mode == "along_ray":
        return True
    truth_xy = samples.truth_cm[:, :2]
    moved = along_ray(samples.xyz_cm, z_new_cm, samples.frame, True)[:, :2]
    return bool(np.sum((moved - truth_xy) ** 2) < np.sum((samples.xyz_cm[:, :2] - truth_xy) ** 2))


def axis_stats(errors_cm: np.ndarray) -> dict[str, dict[str, float]] | None:
    """Mean, std (sample, ddof=1), RMS and max |error| per axis, cm.

    Parameters
    ----------
    errors_cm : ndarray (N, 3)
        measured - truth, cm.

    Returns
    -------
    dict or None
        ``{"x": {"mean_cm", "std_cm", "rms_cm", "max_abs_cm"}, "y": ..., "z": ...}``; None for no
        rows.
    """
    e = np.asarray(errors_cm, dtype=float).reshape(-1, 3)
    if len(e) == 0:
        return None
    out = {}
    for k, axis in enumerate(AXES):
        col = e[:, k]
        out[axis] = {
            "mean_cm": float(np.mean(col)),
            "std_cm": float(np.std(col, ddof=1)) if len(col) > 1 else 0.0,
            "rms_cm": float(np.sqrt(np.mean(col**2))),
            "max_abs_cm": float(np.max(np.abs(col))),
        }
    return out


FitFn = Callable[[Samples], dict[str, Any]]
PredictFn = Callable[[Mapping[str, Any], Samples], np.ndarray]


def kfold_cv(
    samples: Samples, fit: FitFn, predict: PredictFn, k: int, seed: int = 0
) -> dict[str, Any]:
    """k-fold cross-validation of a model on the training placements.

    Each fold is predicted by a model fitted on the other folds; the figures
    are the statistics of those held-out errors (predicted - truth), cm.

    Returns
    -------
    dict
        ``{"k", "n", "axes": axis_stats, "fold_rms_z_cm": [...]}``, or
        ``{"k", "n", "skipped": reason}`` when it cannot run (too few
        placements, a degenerate fold).
    """
    n = len(samples)
    if n < 2 * k:
        return {
            "k": k,
            "n": n,
            "skipped": f"{n} training placements are too few for {k}-fold CV (need {2 * k})",
        }
    order = np.random.default_rng(seed).permutation(n)
    folds = np.array_split(order, k)
    errors = np.full((n, 3), np.nan)
    fold_rms = []
    for held in folds:
        rest = np.setdiff1d(order, held)
        try:
            coef = fit(samples.subset(rest))
            pred = predict(coef, samples.subset(held))
        except NodeError as exc:
            return {"k": k, "n": n, "skipped": f"a fold could not be fitted: {exc.message}"}
        err = pred - samples.truth_cm[held]
        if not np.all(np.isfinite(err)):
            return {
                "k": k,
                "n": n,
                "skipped": "a fold's model gave non-finite predictions on its held-out placements",
            }
        errors[held] = err
        fold_rms.append(float(np.sqrt(np.mean(err[:, 2] ** 2))))
    return {"k": k, "n": n, "axes": axis_stats(errors), "fold_rms_z_cm": fold_rms}


# : A correction whose held-out error is this many times the uncorrected error makes results worse:
# refused.
WORSE_THAN_NONE = 2.0
# : A held-out z error this many times the training residual: the model follows the placements'
# noise.
OVERFIT_RATIO = 3.0
# : Training truth whose median 3-D distance from the located centres is more than this fraction of
# the
# : balls' distance from the cameras is not a stereo error (a few per cent even for a poor
# calibration):
#: it is a truth in another unit (mm) or frame. Fitted, it would move every later location as far.
MAX_TRUTH_GAP_FRACTION = 0.2


def _camera_distance_cm(samples: Samples) -> np.ndarray | None:
    """Each placement's distance from the cameras (cm), or None where the records cannot say."""
    if samples.frame == "left_camera":
        return np.linalg.norm(samples.xyz_cm, axis=1)
    rig = samples.rig or {}
    # z = f B / d, near enough for a plausibility check
    if rig.get("fx_px") and rig.get("baseline_cm"):
        return float(rig["fx_px"]) * float(rig["baseline_cm"]) / samples.disparity_px
    return None


def require_plausible_truth(samples: Samples, label: str) -> None:
    """Refuse training truth that is nowhere near the located centres (another unit or frame).

    A compensation learns ``truth - measured``; a truth in millimetres, or table-frame numbers
    given as left-camera ``x_cm, y_cm, z_cm``, fits as smoothly as a real error (cross-validation
    does not object) and would then move every located ball by tens of centimetres.
    """
    if samples.truth_cm is None or len(samples) == 0:
        return
    gap = np.linalg.norm(samples.truth_cm - samples.xyz_cm, axis=1)
    dist = _camera_distance_cm(samples)
    if dist is None or not np.all(np.isfinite(dist)):
        return
    fraction = float(np.median(gap / dist))
    if fraction <= MAX_TRUTH_GAP_FRACTION:
        return
    i = int(np.argsort(gap)[len(gap) // 2])
    raise NodeError(
        f"{label}: the training truth is far from where the balls were located: by "
        f"{np.median(gap):.3g} cm "
        f"(median of {len(samples)} placements), {fraction:.0%} of their distance from "
        "the cameras, where a stereo "
        f"error is a few per cent (e.g. {samples.ids[i]}: located "
        f"{np.round(samples.xyz_cm[i], 2).tolist()} cm, "
        f"truth {np.round(samples.truth_cm[i], 2).tolist()} cm, {samples.frame} frame). A "
        "correction fitted to this "
        "would move every later location as far.",
        hint="check the truth file: centres in cm (not mm or m); x_cm,y_cm,z_cm only for the "
        "left-camera frame, "
        "table_x_cm,table_y_cm,table_z_cm for the board's table frame; ids that name the "
        "right pairs; "
        "and that the calibration and table frame are this bench's",
    )


def _total_rms(axes: Mapping[str, Any] | None) -> float | None:
    if not axes:
        return None
    return float(np.sqrt(sum(float(axes[a]["rms_cm"]) ** 2 for a in AXES)))


def judge_cross_validation(
    model: Mapping[str, Any], label: str, model_type: str, ctx: Any = None
) -> None:
    """Say what cross-validation says about a fitted model (the honest estimate of its error on new
    placements): refuse one that makes results worse than no correction, warn of one that overfits
    or could not be cross-validated."""
    warn = ctx.warn if ctx is not None and hasattr(ctx, "warn") else (lambda _msg: None)
    cv = model.get("cv") or {}
    if cv.get("skipped"):
        warn(
            f"cross-validation skipped ({cv['skipped']}): the correction's error on new "
            "placements is unknown"
        )
        return
    held, before = _total_rms(cv.get("axes")), _total_rms(model.get("train_before_cm"))
    if held is None or before is None:
        return
    n = model.get("n_train")
    if held > WORSE_THAN_NONE * before:
        raise NodeError(
            f"{label}: cross-validated on its {n} training placements, this {model_type} "
            "correction makes "
            f"the results worse than none (held-out RMS error {held:.3g} cm against "
            f"{before:.3g} cm "
            "uncorrected): it follows the placements' noise, not the error.",
            hint="use fewer coefficients (a lower degree, fewer bins) or more training "
            "placements over "
            "the working range; compensator.none if the rig needs no correction",
        )
    cv_z = float(cv["axes"]["z"]["rms_cm"])
    fit_z = float(((model.get("train_residual_cm") or {}).get("z") or {}).get("rms_cm", np.nan))
    if held > before:
        warn(
            "in cross-validation this correction does not improve on none (held-out RMS "
            f"{held:.3g} cm, "
            f"uncorrected {before:.3g} cm)"
        )
    elif np.isfinite(fit_z) and cv_z > OVERFIT_RATIO * fit_z:
        warn(
            "the correction fits its training placements far better than held-out ones "
            f"(z RMS {fit_z:.3g} cm "
            f"fitted, {cv_z:.3g} cm cross-validated): it may follow their noise; fewer "
            "coefficients would be safer"
        )


def build_model(
    model_type: str,
    samples: Samples,
    fit: FitFn,
    predict: PredictFn,
    inputs: tuple[str, ...],
    label: str,
    cv_folds: int = 5,
    cv_seed: int = 0,
    options: Mapping[str, Any] | None = None,
    robust: FitParams | None = None,
    min_points: int = 1,
    ctx: Any = None,
) -> dict[str, Any]:
    """Fit a model and describe it as a ``CompensationModel`` artifact.

    Parameters
    ----------
    model_type : str
        Key of the apply table (``"polynomial"`` ...).
    samples : Samples
        Training placements (with truth).
    fit, predict : callable
        The model's pure functions.
    inputs : tuple of str
        Location keys the model reads; their training min/max is the valid range.
    label : str
        Node label for errors.
    cv_folds, cv_seed : int
        k-fold cross-validation settings.
    options : mapping, optional
        The fit options, recorded in the artifact.
    robust : FitParams, optional
        With ``outlier_mad`` set, mis-detected placements are left out first
        (:func:`nodes.contracts.compensator._robust.screen_outliers`); None fits every placement.
    min_points : int
        Fewest placements the model can be fitted from (for the screening's refusal).
    ctx : RunContext, optional
        Where to report the placements left out (the run summary shows it).

    Returns
    -------
    dict
        ``{"type", "coefficients", "valid_range", "frame", "n_train", "n_candidates",
        "train_before_cm", "train_residual_cm", "cv", "fit_time_s", "options",
        "outliers": [{"item", "residual_cm", "error_cm"}], "n_outliers", "outlier_threshold_cm"}``;
        every statistic is over the placements kept (``n_train`` of ``n_candidates``).
    """
    from nodes.contracts.compensator._support import describe_support

    n_candidates = len(samples)
    t0 = time.perf_counter()
    screen, coefficients, samples = _screened_fit(
        samples, fit, predict, robust, min_points, label, model_type
    )
    fit_time = time.perf_counter() - t0
    # after the screening, whose refusal of mostly mis-detected placements says more than this one's
    require_plausible_truth(samples, label)
    corrected = predict(coefficients, samples)
    if not np.all(np.isfinite(corrected)):
        raise NodeError(
            f"{label}: the fitted {model_type} model gives non-finite values on its own "
            "training placements.",
            hint="check the training data (distances, disparities) or choose a simpler model.",
        )
    truth = samples.truth_cm
    valid_range = {
        name: {
            "min": float(np.min(samples.variable(name))),
            "max": float(np.max(samples.variable(name))),
        }
        for name in inputs
    }
    model = {
        "type": model_type,
        "coefficients": coefficients,
        "valid_range": valid_range,
        "frame": samples.frame,
        "n_train": len(samples),
        "n_candidates": n_candidates,
        **screen.describe(),
        "train_before_cm": axis_stats(samples.xyz_cm - truth),
        "train_residual_cm": axis_stats(corrected - truth),
        "cv": kfold_cv(samples, fit, predict, cv_folds, cv_seed),
        "fit_time_s": float(fit_time),
        "options": dict(options or {}),
        "rig": samples.rig,
        # Where the training placements say the model holds (compensator.apply flags the rest).
        "support": describe_support(samples.xyz_cm, corrected, truth),
    }
    judge_cross_validation(model, label, model_type, ctx)
    if screen.outliers and ctx is not None and hasattr(ctx, "warn"):
        ctx.warn(_left_out_note(screen, n_candidates))
    return model


def _left_out_note(screen: Any, n_candidates: int) -> str:
    """The warning that names the training placements the screening left out (8 at most)."""
    listed = ", ".join(
        f"{o['item']} ({o['residual_cm']:.3g} cm)"
        if o["residual_cm"] is not None
        else f"{o['item']} (undefined)"
        for o in screen.outliers[:8]
    )
    more = f", +{len(screen.outliers) - 8} more" if len(screen.outliers) > 8 else ""
    return (
        f"left {len(screen.outliers)} of {n_candidates} training placements out of "
        "the fit: their measurement "
        "disagrees with the truth by far more than the rest (residual > "
        f"{screen.threshold_cm:.3g} cm): "
        f"{listed}{more}; see 'outliers' in the model"
    )


def _screened_fit(
    samples: Samples,
    fit: FitFn,
    predict: PredictFn,
    robust: FitParams | None,
    min_points: int,
    label: str,
    model_type: str,
) -> tuple[Any, Any, Samples]:
    """``(screen, coefficients, the placements kept)``: the fit, after leaving mis-detected
    placements out when ``robust.outlier_mad`` is set; a failed fit is a NodeError naming
    ``label``."""
    from nodes.contracts.compensator._robust import Screen, screen_outliers

    try:
        if robust is not None and robust.outlier_mad is not None:
            screen, coefficients = screen_outliers(
                samples,
                fit,
                predict,
                robust.outlier_mad,
                robust.min_inlier_fraction,
                min_points,
                label,
                robust.max_residual_sigma,
            )
            samples = samples.subset(screen.inliers)
        else:
            screen, coefficients = Screen(inliers=np.arange(len(samples))), fit(samples)
    except NodeError as exc:
        if exc.message.startswith(label):
            raise
        raise NodeError(
            f"{label}: {exc.message}",
            hint=exc.hint or "use fewer coefficients or more, better spread placements.",
        ) from None
    except np.linalg.LinAlgError as exc:
        raise NodeError(
            f"{label}: the least-squares fit of the {model_type} model failed ({exc}).",
            hint="use fewer coefficients or more, better spread placements.",
        ) from None
    return screen, coefficients, samples
