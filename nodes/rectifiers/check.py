"""``rectifier.check``: is the calibration right for the pictures it is applied to?

Features matched between the raw left and right images of the scene pairs (ORB, AKAZE or SIFT from
OpenCV; matches kept when mutually best, clear of the second best, and consistent with one epipolar
geometry -- RANSAC on the fundamental matrix, which repetitive texture cannot fool as easily as a
single match), their points rectified with the calibration, and their vertical disagreement
measured: after a right rectification a point lies on the same row in both images. It needs no
corners, so it works for every calibration source (a run's JSON, OpenCV files, ROS, a given camera).
Public: :func:`epipolar_check`; the nodes :func:`check` (a collection of pairs, once),
:func:`confirm` (the same, then the rectification passed on) and :func:`gate` (a pair per cycle of a
live loop, checked every n-th, passed on while the calibration holds).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from nodes.rectifiers.opencv import rectified_points
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["CheckParams", "GateParams", "check", "confirm", "epipolar_check", "gate"]

# (3000 features: with 1500, OpenCV's real chessboard pairs gave too few good matches for a clean
# verdict)
_DETECTORS = {
    "orb": lambda: cv2.ORB_create(3000),
    "sift": lambda: cv2.SIFT_create(3000),
    # (OpenCV 5 keeps AKAZE in the contrib module xfeatures2d, OpenCV 4 in the main one)
    "akaze": lambda: (
        cv2.AKAZE_create if hasattr(cv2, "AKAZE_create") else cv2.xfeatures2d.AKAZE_create
    )(),
}


class CheckParams(Params):
    features: Literal["orb", "akaze", "sift"] = Field(
        "orb", description="OpenCV feature detector (name)."
    )
    max_pairs: int = Field(
        4, ge=1, le=200, description="Pairs checked, evenly spread over the collection (count)."
    )
    warn_dy_px: float = Field(
        0.5,
        gt=0,
        description="Vertical disagreement (the median, or its part that a shift "
        "or tilt across the image explains) above which the run "
        "warns (px).",
    )
    refuse_dy_px: float = Field(
        2.0,
        gt=0,
        description="... above which the node refuses, so nothing is located "
        "with this calibration (px).",
    )
    min_matches: int = Field(
        20, ge=5, description="Fewest consistent matches for a verdict (count)."
    )


def _gray(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


def _matches(left: np.ndarray, right: np.ndarray, features: str) -> tuple[np.ndarray, np.ndarray]:
    """Raw pixel positions (N, 2) of matches that are mutual, distinct and epipolar-consistent."""
    det = _DETECTORS[features]()
    kl, dl = det.detectAndCompute(_gray(left), None)
    kr, dr = det.detectAndCompute(_gray(right), None)
    if dl is None or dr is None or len(kl) < 8 or len(kr) < 8:
        return np.empty((0, 2)), np.empty((0, 2))
    norm = cv2.NORM_HAMMING if dl.dtype == np.uint8 else cv2.NORM_L2
    bf = cv2.BFMatcher(norm)
    fwd = bf.knnMatch(dl, dr, k=2)
    back = {m.queryIdx: m.trainIdx for m in bf.match(dr, dl)}
    good = [
        p[0]
        for p in fwd
        if len(p) == 2
        and p[0].distance < 0.8 * p[1].distance
        and back.get(p[0].trainIdx) == p[0].queryIdx
    ]
    a = np.float64([kl[m.queryIdx].pt for m in good]).reshape(-1, 2)
    b = np.float64([kr[m.trainIdx].pt for m in good]).reshape(-1, 2)
    return _epipolar_inliers(a, b) if len(a) >= 8 else (a, b)


def _epipolar_inliers(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The matches (px, N x 2 each) that a RANSAC fundamental matrix keeps (1 px, 99.9 %)."""
    # maxIters given (1000, the default) so that the call is the binding's first overload:
    # trying another first can segfault on a stop signal (nodes.contracts.cv_overloads).
    _F, inl = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, 1.0, 0.999, 1000)
    keep = inl.ravel().astype(bool) if inl is not None else np.zeros(len(a), bool)
    return a[keep], b[keep]


def epipolar_check(rect: dict, pairs: list[dict], params: CheckParams) -> dict:
    """Vertical disagreement (px) and disparity sign of matched features after rectification.

    Returns ``{"verdict": "ok" | "warn" | "refuse", "cause": str | None, "dy_median_px",
    "dy_p90_px", "n_matches", "positive_disparity_fraction", "pairs": [...]}``.
    """
    w, h = rect.get("source_size", rect["image_size"])
    dys, disp, per_pair = [], [], []
    for pair in pairs:
        left, right = pair["left"], pair["right"]
        if left.shape[:2] != (h, w) or right.shape[:2] != (h, w):
            return {
                "verdict": "refuse",
                "cause": f"another resolution: the images are {left.shape[1]}x"
                f"{left.shape[0]} px, the calibration is for {w}x{h}",
                "pairs": [],
            }
        a, b = _matches(left, right, params.features)
        if len(a) == 0:
            per_pair.append({"id": pair.get("id"), "n_matches": 0})
            continue
        ra, rb = rectified_points(rect, a, "left"), rectified_points(rect, b, "right")
        dy, d = ra[:, 1] - rb[:, 1], ra[:, 0] - rb[:, 0]
        dys.append(np.column_stack([dy, ra]))
        disp.append(d)
        per_pair.append(
            {
                "id": pair.get("id"),
                "n_matches": int(len(dy)),
                "dy_median_px": round(float(np.median(np.abs(dy))), 3),
            }
        )
    rows = np.concatenate(dys) if dys else np.empty((0, 3))
    out = {"n_matches": int(len(rows)), "pairs": per_pair}
    if len(rows) < params.min_matches:
        return {
            **out,
            "verdict": "unknown",
            "cause": f"only {len(rows)} consistent feature matches (fewer than "
            f"{params.min_matches}): too little texture to check",
        }
    return _verdict(out, rows, np.concatenate(disp), (w, h), params)


def _verdict(out: dict, rows: np.ndarray, d: np.ndarray, size: tuple, params: CheckParams) -> dict:
    """``out`` with the matches' statistics and the verdict: swapped images, a camera moved (or
    another rig's calibration), or ok."""
    w, h = size
    dy = np.abs(rows[:, 0])
    out.update(
        dy_median_px=round(float(np.median(dy)), 3),
        dy_p90_px=round(float(np.percentile(dy, 90)), 3),
        dy_systematic_px=round(_systematic(rows, w, h), 3),
        positive_disparity_fraction=round(float((d > 0).mean()), 3),
    )
    if out["positive_disparity_fraction"] < 0.2:
        return {
            **out,
            "verdict": "refuse",
            "cause": "the disparities are negative almost everywhere: the left "
            "and right images are swapped (cables or device numbers)",
        }
    worst = max(out["dy_median_px"], out["dy_systematic_px"])
    if worst <= params.warn_dy_px:
        return {**out, "verdict": "ok", "cause": None}
    return {
        **out,
        "verdict": "refuse" if worst > params.refuse_dy_px else "warn",
        "cause": f"matched points lie {out['dy_median_px']:.2f} px apart vertically after "
        "rectification "
        f"(median; {out['dy_systematic_px']:.2f} px of it a shift or tilt across the "
        "image): a camera "
        "moved since the calibration, or the calibration is another rig's",
    }


def _systematic(rows: np.ndarray, w: float, h: float) -> float:
    """Median |dy| (px) explained by a shift and a tilt across the image (dy ~ a + b x + c y,
    robust): a moved camera tilts or shifts every row; the matcher's own noise has no such
    pattern."""
    x, y = (rows[:, 1] - w / 2) / w, (rows[:, 2] - h / 2) / h
    A = np.column_stack([np.ones_like(x), x, y])
    dev = np.abs(rows[:, 0] - np.median(rows[:, 0]))
    keep = dev < 5 * (np.median(dev) + 1e-3)
    coef = np.linalg.lstsq(A[keep], rows[keep, 0], rcond=None)[0]
    return float(np.median(np.abs(A @ coef)))


def _checked(params: CheckParams, rectification: dict, pairs, ctx) -> dict:
    """The health record of the check on the pairs; NodeError on a refusal, a warning on doubt."""
    items = list(pairs.values()) if isinstance(pairs, dict) else list(pairs)
    if not items:
        raise NodeError(
            "rectifier.check: no pairs to check the calibration on.",
            hint="wire it to the scene pairs",
        )
    step = max(1, len(items) // params.max_pairs)
    got = epipolar_check(rectification, items[::step][: params.max_pairs], params)
    first = ("verdict", "cause", "dy_median_px", "dy_systematic_px", "dy_p90_px", "n_matches")
    # (the verdict first: the page shows it first)
    health = {**{k: got[k] for k in first if k in got}, **got}
    said = _said(f"calibration check on {len(health['pairs'])} pair(s)", health)
    if health["verdict"] == "refuse":
        raise NodeError(
            f"rectifier.check: {said}.",
            hint="recalibrate these cameras, or load their own calibration "
            "(swapped images: swap left and right in the source)",
        )
    if ctx is not None and health["verdict"] in ("warn", "unknown"):
        ctx.warn(said)
    return health


def _said(what: str, health: dict) -> str:
    """The verdict in words: ``what: verdict, median |dy| ... ; cause``."""
    return (
        f"{what}: {health['verdict']}"
        + (
            f", median |dy| {health['dy_median_px']} px, 90 % {health['dy_p90_px']} px over "
            f"{health['n_matches']} matches"
            if "dy_median_px" in health
            else ""
        )
        + (f"; {health['cause']}" if health.get("cause") else "")
    )


_INPUTS = {
    "rectification": In("Rectification"),
    "pairs": In(
        "StereoPair", gather=True, description="The scene pairs the calibration is applied to."
    ),
}
_HEALTH = Out(
    "any",
    save=True,
    headline=True,
    description="Vertical disagreement after rectification (px), matches, disparity sign.",
)


@node(
    "rectifier.check", inputs=_INPUTS, outputs={"health": _HEALTH}, params=CheckParams, version="1"
)
def check(params: CheckParams, rectification: dict, pairs, ctx=None) -> dict:
    """Check the calibration on the scene pairs: matched features must meet on one row after
    rectification."""
    return {"health": _checked(params, rectification, pairs, ctx)}


@node(
    "rectifier.confirm",
    inputs=_INPUTS,
    params=CheckParams,
    version="1",
    outputs={
        "health": _HEALTH,
        "rectification": Out(
            "Rectification",
            description="The rectification, passed on "
            "once the pairs confirm it: what reads it never runs on a "
            "refused calibration.",
        ),
    },
)
def confirm(params: CheckParams, rectification: dict, pairs, ctx=None) -> dict:
    """rectifier.check, then the rectification passed on: wire what moves an arm to its output."""
    return {"health": _checked(params, rectification, pairs, ctx), "rectification": rectification}


class GateParams(CheckParams):
    every_n: int = Field(
        10,
        ge=1,
        le=100000,
        description="Check the first pair and then every n-th one (count): "
        "the pairs between pass unchecked, at no cost.",
    )


@node(
    "rectifier.gate",
    inputs={
        "rectification": In("Rectification"),
        "pair": In("StereoPair", description="A scene pair (per cycle)."),
    },
    outputs={
        "pair": Out(
            "StereoPair", description="The same pair, passed on once the calibration is trusted."
        ),
        "health": Out(
            "any", optional=True, description="The last check (rectifier.check's record)."
        ),
    },
    params=GateParams,
    version="1",
)
def gate(params: GateParams, rectification: dict, pair: dict, ctx=None) -> dict:
    """Pass pairs on while the calibration holds; check it on the first pair and every n-th one
    after."""
    # what the gate keeps across the cycles of a run: calls so far, the last check
    state = ctx.resource("gate", dict) if ctx is not None else None
    state = {} if state is None else state  # (an empty dict is the kept one: not `or {}`)
    state["n"] = state.get("n", 0) + 1
    if "last" not in state or (state["n"] - 1) % params.every_n == 0:
        state["last"] = last = epipolar_check(rectification, [pair], params)
        said = _said(f"calibration check on pair {pair.get('id')}", last)
        if last["verdict"] == "refuse":  # lasting: no later cycle may pick with this calibration
            raise NodeError(
                f"rectifier.gate: {said}; nothing is picked with this calibration.",
                lasting=True,
                hint="recalibrate these cameras, or load their own calibration (swapped "
                "images: swap "
                "left and right in the camera source)",
            )
        if ctx is not None and last["verdict"] == "warn":
            ctx.warn(said)
    return {"pair": pair, "health": {k: v for k, v in state["last"].items() if k != "pairs"}}
