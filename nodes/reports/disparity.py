"""``report.disparity``: how good dense disparity maps are, against ground-truth disparity images.

A reduce over ``DisparityMap`` items (``disparity.dense``): per pair the Middlebury scores --
*fill*, the share of pixels with a known true disparity that got one, and *bad-T*, the share of
those filled pixels more than ``threshold_px`` from the truth -- then their mean over the pairs,
as ``Metrics`` (so ``stereograph compare`` can rank SGBM settings by bad-2.0) and a per-pair table.

The truth is an image whose grey level times ``truth_scale`` is the disparity in px, 0 where it is
unknown (the Middlebury convention), or a PFM of disparities (inf = unknown). With no ``truth`` the
report uses the truth the source found beside each pair (``truth_disparity_path``); with no
``truth_scale`` the scale is read from the data, among the datasets' conventions (1, 1/2, 1/3, 1/4,
1/8, 1/16).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nodes.contracts.disparity_scores import bad_pixels
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["DisparityScoreParams", "disparity_score", "truth_path"]


class DisparityScoreParams(Params):
    """Parameters of ``report.disparity``."""

    truth: str | None = Field(
        None,
        description="Ground-truth disparity image, relative to the pipeline file; "
        "`{id}` is replaced by the pair's id (text). None = the dataset's own truth found "
        "beside each pair by source.files (disp2.png for im2.png, disp0.pfm, aloeGT.png).",
    )
    truth_scale: float | None = Field(
        None,
        gt=0,
        description="Disparity per grey level of the truth image "
        "(px per level; 1 for full-size Middlebury 2005-2006, 0.25 for 2003's x4 "
        "maps). None = read from the data among 1, 1/2, 1/3, 1/4, 1/8, 1/16 (said in a "
        "warning); PFM truth is in px.",
    )
    threshold_px: float = Field(
        2.0,
        gt=0,
        le=50,
        description="A pixel is bad when its disparity is more than "
        "this far from the truth (px; 2.0 = bad-2.0).",
    )


def truth_path(params: DisparityScoreParams, pipeline_dir: Path, pair_id: str = "*") -> Path:
    """The truth image of one pair (``{id}`` filled in), resolved from the pipeline's folder."""
    p = Path(params.truth.replace("{id}", str(pair_id))).expanduser()
    return p if p.is_absolute() else pipeline_dir / p


#: px per grey level of the datasets' truth images: full size, half, third, Middlebury 2003 (x4),
#: 2001 Venus (x8) and Tsukuba (x16)
TRUTH_SCALES = (1.0, 1 / 2, 1 / 3, 1 / 4, 1 / 8, 1 / 16)


def read_truth(path: Path) -> np.ndarray | None:
    """A truth disparity image as float32 levels, 0 = unknown (a PFM's inf too); None if
    unreadable."""
    truth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if truth is None:
        return None
    truth = (truth[..., 0] if truth.ndim == 3 else truth).astype(np.float32)
    return np.where(np.isfinite(truth) & (truth > 0), truth, np.float32(0))


def scale_from_data(disp: np.ndarray, truth_levels: np.ndarray) -> float:
    """The :data:`TRUTH_SCALES` entry closest (in ratio) to the median of matched / true levels."""
    both = (truth_levels > 0) & np.isfinite(disp) & (disp > 0)
    if both.sum() < 100:
        return 1.0
    ratio = float(np.median(disp[both] / truth_levels[both]))
    return min(TRUTH_SCALES, key=lambda s: abs(np.log(ratio / s)))


def _reads(params: DisparityScoreParams, pipeline_dir: Path) -> list[Path]:
    if params.truth is None:
        return []  # the truth beside each pair: source.files reads it into its key
    pattern = truth_path(params, pipeline_dir)
    return sorted(pattern.parent.glob(pattern.name)) if "{id}" in params.truth else [pattern]


def _truth_of(
    params: DisparityScoreParams, dmap: dict, pdir: Path, pair_id: str, label: str
) -> tuple[Path, np.ndarray]:
    """``(path, image)`` of a pair's ground-truth disparity: beside the pair, or ``truth``;
    NodeError when there is none to read."""
    given = dmap.get("truth_disparity_path") if params.truth is None else None
    path = Path(given) if given else truth_path(params, pdir, pair_id) if params.truth else None
    truth = read_truth(path) if path is not None else None
    if truth is None:
        raise NodeError(
            f"{label}: no readable truth image for pair '{pair_id}'"
            + (f" at {path}." if path else ": none beside the pair and no `truth` param."),
            hint="set `truth` to the ground-truth disparity image (relative to the "
            "pipeline file; "
            "`{id}` stands for the pair id)",
        )
    return path, truth


@node(
    "report.disparity",
    inputs={
        "disparity_map": In(
            "DisparityMap", gather=True, description="Dense disparity maps (disparity.dense)."
        )
    },
    outputs={
        "metrics": Out(
            "Metrics",
            save=True,
            optional=True,
            headline=True,
            description="n_pairs, fill_fraction, bad_<T>px_fraction, match_s (means over the "
            "pairs).",
        ),
        "pairs": Out("any", save=True, optional=True, description="The same scores per pair."),
    },
    params=DisparityScoreParams,
    version="1",
    reads=_reads,
)
def disparity_score(params: DisparityScoreParams, disparity_map, ctx=None):
    """Fill and bad-pixel fraction of dense disparity maps against ground-truth disparity images."""
    pdir = ctx.pipeline_dir if ctx is not None else Path.cwd()
    label = f"report.disparity '{ctx.node_name}'" if ctx is not None else "report.disparity"
    bad_name = f"bad_{params.threshold_px:g}px_fraction"
    rows = []
    for item, dmap in (disparity_map or {}).items():
        pair_id = str(dmap.get("id") or item)
        path, truth = _truth_of(params, dmap, pdir, pair_id, label)
        disp = np.asarray(dmap["disparity_px"], dtype=np.float32)
        if truth.shape != disp.shape:
            raise NodeError(
                f"{label}: the truth {path.name} is {truth.shape[1]}x{truth.shape[0]} px but pair "
                f"'{pair_id}''s disparity map is {disp.shape[1]}x{disp.shape[0]} px.",
                hint="use the truth image of the same resolution as the matched pair",
            )
        scale = params.truth_scale or (
            1.0 if path.suffix.lower() == ".pfm" else scale_from_data(disp, truth)
        )
        if params.truth_scale is None and scale != 1.0 and ctx is not None:
            ctx.warn(
                f"pair '{pair_id}': the truth {path.name} read as {scale:.4g} px per grey "
                "level (from the "
                "data); set truth_scale if that is wrong"
            )
        fill, bad = bad_pixels(disp, truth * scale, params.threshold_px)
        rows.append(
            {
                "pair": pair_id,
                "truth": path.name,
                "truth_scale": scale,
                "fill_fraction": fill,
                bad_name: None if np.isnan(bad) else bad,
                "match_s": dmap.get("compute_seconds"),
            }
        )
    if not rows:
        raise NodeError(
            f"{label}: no disparity map to score.", hint="wire `disparity_map` to disparity.dense"
        )

    def mean(key: str) -> float | None:
        vals = [r[key] for r in rows if isinstance(r[key], (int, float))]
        return float(np.mean(vals)) if vals else None

    metrics = {
        "n_pairs": len(rows),
        "fill_fraction": mean("fill_fraction"),
        bad_name: mean(bad_name),
        "match_s": mean("match_s"),
    }
    return {"metrics": metrics, "pairs": rows}
