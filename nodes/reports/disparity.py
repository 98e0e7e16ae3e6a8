"""``report.disparity``: how good dense disparity maps are, against ground-truth disparity images.

A reduce over ``DisparityMap`` items (``disparity.dense``): per pair the Middlebury scores --
*fill*, the share of pixels with a known true disparity that got one, and *bad-T*, the share of
those filled pixels more than ``threshold_px`` from the truth -- then their mean over the pairs,
as ``Metrics`` (so ``stereograph compare`` can rank SGBM settings by bad-2.0) and a per-pair table.

The truth is an image whose grey level times ``truth_scale`` is the disparity in px, 0 where it is
unknown (the Middlebury convention; the full-size ``aloeGT.png`` shipped with OpenCV's samples
has ``truth_scale`` 1).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nodes.disparity.dense import bad_pixels
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["DisparityScoreParams", "disparity_score", "truth_path"]


class DisparityScoreParams(Params):
    """Parameters of ``report.disparity``."""

    truth: str = Field(..., description="Ground-truth disparity image, relative to the pipeline file; `{id}` "
                                        "is replaced by the pair's id (text).")
    truth_scale: float = Field(1.0, gt=0, description="Disparity per grey level of the truth image "
                                                      "(px per level; 1 for full-size Middlebury, 0.25 for a "
                                                      "16-bit x4 map).")
    threshold_px: float = Field(2.0, gt=0, le=50, description="A pixel is bad when its disparity is more than "
                                                               "this far from the truth (px; 2.0 = bad-2.0).")


def truth_path(params: DisparityScoreParams, pipeline_dir: Path, pair_id: str = "*") -> Path:
    """The truth image of one pair (``{id}`` filled in), resolved from the pipeline's folder."""
    p = Path(params.truth.replace("{id}", str(pair_id))).expanduser()
    return p if p.is_absolute() else pipeline_dir / p


def _reads(params: DisparityScoreParams, pipeline_dir: Path) -> list[Path]:
    pattern = truth_path(params, pipeline_dir)
    return sorted(pattern.parent.glob(pattern.name)) if "{id}" in params.truth else [pattern]


@node(
    "report.disparity",
    inputs={"disparity_map": In("DisparityMap", gather=True, description="Dense disparity maps (disparity.dense).")},
    outputs={
        "metrics": Out("Metrics", save=True, optional=True, headline=True,
                       description="n_pairs, fill_fraction, bad_<T>px_fraction, match_s (means over the pairs)."),
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
        path = truth_path(params, pdir, pair_id)
        truth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if truth is None:
            raise NodeError(f"{label}: no readable truth image for pair '{pair_id}' at {path}.",
                            hint="set `truth` to the ground-truth disparity image (relative to the pipeline file; "
                                 "`{id}` stands for the pair id)")
        if truth.ndim == 3:
            truth = truth[..., 0]
        disp = np.asarray(dmap["disparity_px"], dtype=np.float32)
        if truth.shape != disp.shape:
            raise NodeError(f"{label}: the truth {path.name} is {truth.shape[1]}x{truth.shape[0]} px but pair "
                            f"'{pair_id}''s disparity map is {disp.shape[1]}x{disp.shape[0]} px.",
                            hint="use the truth image of the same resolution as the matched pair")
        fill, bad = bad_pixels(disp, truth.astype(np.float32) * params.truth_scale, params.threshold_px)
        rows.append({"pair": pair_id, "fill_fraction": fill, bad_name: None if np.isnan(bad) else bad,
                     "match_s": dmap.get("compute_seconds")})
    if not rows:
        raise NodeError(f"{label}: no disparity map to score.", hint="wire `disparity_map` to disparity.dense")

    def mean(key: str) -> float | None:
        vals = [r[key] for r in rows if isinstance(r[key], (int, float))]
        return float(np.mean(vals)) if vals else None

    metrics = {"n_pairs": len(rows), "fill_fraction": mean("fill_fraction"), bad_name: mean(bad_name),
               "match_s": mean("match_s")}
    return {"metrics": metrics, "pairs": rows}
