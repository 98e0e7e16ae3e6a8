"""``source.calib_files``: chessboard calibration pairs from image files."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from nodes.sources._files import DEFAULT_MAX_MPX, PAIRING_DOC, pairs_for, read_image
from stereograph.api import Field, NodeError, Out, Params, PathField, node


class CalibFilesParams(Params):
    folder: str = PathField(
        ..., description="Folder of the images (relative to the pipeline file)."
    )
    left_glob: str = Field(
        "*left*", description="Glob of the left images in `folder` (e.g. left*.jpg, left/*.png)."
    )
    right_glob: str = Field("*right*", description="Glob of the right images in `folder`.")
    pairing: Literal["auto", "globs"] = Field("auto", description=PAIRING_DOC)
    board_cols: int = Field(9, ge=3, le=40, description="Chessboard inner corners per row (count).")
    board_rows: int = Field(
        6, ge=3, le=40, description="Chessboard inner corners per column (count)."
    )
    square_cm: float = Field(
        1.0, gt=0, description="Square size, cm (1.0 = lengths in squares when unknown)."
    )
    max_image_mpx: float = Field(
        DEFAULT_MAX_MPX,
        gt=0,
        description="Largest image read, megapixels (checked from "
        "the file's header before decoding); a view with a larger image is rejected.",
    )


def _reads(params: CalibFilesParams, pipeline_dir: Path) -> list[Path]:
    folder = Path(params.folder).expanduser()
    folder = folder if folder.is_absolute() else pipeline_dir / folder
    try:
        return [p for _, l, r in pairs_for(params, folder)[0] for p in (l, r)]
    except NodeError:
        return []  # the node itself reports the problem when it runs


@node(
    "source.calib_files",
    outputs={"views": Out("StereoViews", description="Chessboard pairs (no ground truth).")},
    params=CalibFilesParams,
    version="1",
    reads=_reads,
)
def calib_files(params: CalibFilesParams, ctx=None) -> dict:
    """Read chessboard calibration pairs (left/right matched by name) from a folder."""
    folder = ctx.path(params.folder) if ctx is not None else Path(params.folder).expanduser()
    pairs, rule = pairs_for(params, folder)
    if ctx is not None and rule.startswith("the dataset"):
        ctx.warn(f"{len(pairs)} pair(s) paired by {rule}")
    views, size, rejected = [], None, {}
    for k, (pid, lp, rp) in enumerate(pairs):
        if ctx is not None:
            ctx.progress(k, len(pairs), "views")
        try:
            left = read_image(lp, color=False, max_mpx=params.max_image_mpx)
            right = read_image(rp, color=False, max_mpx=params.max_image_mpx)
        except NodeError as exc:  # rejected with its reason, like a view without a board
            rejected[pid] = exc.message
            continue
        for p, im in ((lp, left), (rp, right)):
            s = [int(im.shape[1]), int(im.shape[0])]
            if size is None:
                size = s
            elif s != size:
                raise NodeError(
                    f"image {p} is {s[0]}x{s[1]} but the others are {size[0]}x{size[1]}.",
                    hint="calibrate with images of one resolution from the same cameras",
                )
        views.append(
            {"id": pid, "left": left, "right": right, "left_path": str(lp), "right_path": str(rp)}
        )
    if rejected and ctx is not None:
        ctx.warn(
            f"rejected {len(rejected)} unreadable view(s): "
            + "; ".join(f"{k}: {v}" for k, v in rejected.items())
        )
    if not views:
        raise NodeError(
            f"none of the {len(pairs)} views could be read: "
            + "; ".join(f"{k}: {v}" for k, v in list(rejected.items())[:5]),
            hint="replace or remove the unreadable images",
        )
    return {
        "views": {
            "views": views,
            "image_size": size,
            "rejected": rejected,
            "board": {
                "cols": params.board_cols,
                "rows": params.board_rows,
                "square_cm": params.square_cm,
                # a square size nobody gave means lengths in squares, and the exports say so
                "length_unit": "cm" if "square_cm" in params.model_fields_set else "squares",
            },
            "truth": None,
        }
    }
