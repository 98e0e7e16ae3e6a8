"""``source.files``: stereo pairs from image files, with optional ground truth from JSON or CSV."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from nodes.sources._files import DEFAULT_MAX_MPX, list_pairs, read_image
from stereograph.api import Field, NodeError, Out, Params, node

__all__ = ["FilesParams", "files", "read_truth"]


def read_truth(path: Path) -> dict[str, dict]:
    """Ground truth per pair id from a JSON or CSV file.

    JSON: ``{pair_id: {"center_left_cm": [x, y, z], "radius_cm": r, ...}}`` or a
    list of such records with an ``"id"`` key. CSV: columns ``id, x_cm, y_cm,
    z_cm`` (ball centre, left-camera frame) and optionally ``radius_cm``,
    ``table_x_cm, table_y_cm, table_z_cm``.
    """
    if not path.is_file():
        raise NodeError(f"truth file {path} does not exist.", hint="fix the `truth` parameter or remove it")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
            if isinstance(data, list):
                data = {str(r["id"]): r for r in data}
            return {str(k): dict(v) for k, v in data.items()}
        out = {}
        with path.open(newline="") as fh:
            for row in csv.DictReader(fh):
                t = {"center_left_cm": [float(row["x_cm"]), float(row["y_cm"]), float(row["z_cm"])],
                     "center_table_cm": None, "radius_cm": float(row["radius_cm"]) if row.get("radius_cm") else None}
                if row.get("table_x_cm"):
                    t["center_table_cm"] = [float(row[f"table_{a}_cm"]) for a in "xyz"]
                out[str(row["id"])] = t
        return out
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise NodeError(f"cannot parse truth file {path}: {exc!r}.",
                        hint="JSON {id: {center_left_cm: [x,y,z]}} or CSV with columns id,x_cm,y_cm,z_cm") from exc


class FilesParams(Params):
    folder: str = Field(..., description="Folder of the images (relative to the pipeline file).")
    left_glob: str = Field("left*", description="Glob of the left images (e.g. left*.png, left/*.png).")
    right_glob: str = Field("right*", description="Glob of the right images.")
    truth: str | None = Field(None, description="Optional JSON/CSV ground-truth file (relative to the pipeline).")
    train_fraction: float = Field(0.5, ge=0, le=1, description="Share of pairs marked split=train (0..1).")
    seed: int = Field(0, ge=0, description="Seed of the train/test split.")
    max_image_mpx: float = Field(DEFAULT_MAX_MPX, gt=0, description="Largest image read, megapixels (checked from "
                                 "the file's header before decoding); a pair with a larger image is skipped.")
    image_size_px: tuple[int, int] | None = Field(None, description="Expected image size, width and height in "
                                                  "pixels (the calibration's image_size); a pair of another size is "
                                                  "skipped before decoding. None = any size.")


def _reads(params: FilesParams, pipeline_dir: Path) -> list[Path]:
    folder = Path(params.folder).expanduser()
    folder = folder if folder.is_absolute() else pipeline_dir / folder
    try:
        paths = [p for _, l, r in list_pairs(folder, params.left_glob, params.right_glob) for p in (l, r)]
    except NodeError:
        paths = []
    if params.truth:
        t = Path(params.truth).expanduser()
        paths.append(t if t.is_absolute() else pipeline_dir / t)
    return paths


@node(
    "source.files",
    outputs={"pairs": Out("StereoPair", collection=True, description="Stereo pairs read from files.")},
    params=FilesParams,
    version="1",
    reads=_reads,
)
def files(params: FilesParams, ctx=None) -> dict:
    """Read stereo pairs from a folder (left/right matched by name), with optional ground truth."""
    resolve = ctx.path if ctx is not None else (lambda v: Path(v).expanduser())
    pairs_list = list_pairs(resolve(params.folder), params.left_glob, params.right_glob)
    truth = read_truth(resolve(params.truth)) if params.truth else {}
    unknown = sorted(set(truth) - {pid for pid, _, _ in pairs_list})
    if truth and unknown and ctx is not None:
        ctx.warn(f"truth rows without images: {', '.join(unknown[:10])}")
    rng = np.random.default_rng([params.seed, 3])
    out, skipped = {}, {}
    for pid, lp, rp in pairs_list:
        split = "train" if rng.random() < params.train_fraction else "test"  # drawn for every pair: a skip
        try:                                                                # leaves the others' split as it was
            kw = {"max_mpx": params.max_image_mpx, "expect_size": params.image_size_px}
            left, right = read_image(lp, **kw), read_image(rp, **kw)
            if left.shape != right.shape:
                raise NodeError(f"{lp.name} is {left.shape[1]}x{left.shape[0]} but {rp.name} is "
                                f"{right.shape[1]}x{right.shape[0]}.", hint="both cameras must give the same size")
        except NodeError as exc:  # one bad pair costs that pair only
            skipped[pid] = exc.message
            if ctx is not None:
                ctx.warn(f"pair {pid} skipped: {exc.message}")
            continue
        out[pid] = {"id": pid, "left": left, "right": right, "truth": truth.get(pid),
                    "split": split,
                    "left_path": str(lp), "right_path": str(rp)}
    if not out:
        raise NodeError(f"none of the {len(pairs_list)} pairs could be read: "
                        + "; ".join(f"{k}: {v}" for k, v in list(skipped.items())[:5]),
                        hint="replace or remove the unreadable images")
    return {"pairs": out}
