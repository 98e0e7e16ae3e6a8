"""``source.files``: stereo pairs from image files, with optional ground truth from JSON or CSV."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from nodes.sources._files import DEFAULT_MAX_MPX, PAIRING_DOC, pairs_for, read_image, truth_beside
from nodes.sources._truth import read_truth_file, truth_split
from stereograph.api import Field, NodeError, Out, Params, PathField, node

__all__ = ["FilesParams", "files", "read_truth"]


def read_truth(path: Path) -> dict[str, dict]:
    """Ground truth per pair id from a JSON or CSV file (see :mod:`nodes.sources._truth`)."""
    return read_truth_file(path)[0]


class FilesParams(Params):
    folder: str = PathField(
        ..., description="Folder of the images (relative to the pipeline file)."
    )
    left_glob: str = Field(
        "*left*", description="Glob of the left images (e.g. left*.png, 007_left.png, left/*.png)."
    )
    right_glob: str = Field("*right*", description="Glob of the right images.")
    pairing: Literal["auto", "globs"] = Field("auto", description=PAIRING_DOC)
    truth: str | None = PathField(
        None,
        description="Optional JSON/CSV ground-truth file (relative to the pipeline). It "
        "decides the split: the pairs it lists are train, the others test, "
        "unless it has a split column (train/test), which rules.",
    )
    train_fraction: float = Field(
        0.5,
        ge=0,
        le=1,
        description="Share of pairs marked split=train (0..1), at random "
        "(seed); only without a truth file.",
    )
    seed: int = Field(0, ge=0, description="Seed of the train/test split.")
    max_image_mpx: float = Field(
        DEFAULT_MAX_MPX,
        gt=0,
        description="Largest image read, megapixels (checked from "
        "the file's header before decoding); a pair with a larger image is skipped.",
    )
    image_size_px: tuple[int, int] | None = Field(
        None,
        description="Expected image size, width and height in "
        "pixels (the calibration's image_size); a pair of another size is "
        "skipped before decoding. None = any size.",
    )


def _reads(params: FilesParams, pipeline_dir: Path) -> list[Path]:
    folder = Path(params.folder).expanduser()
    folder = folder if folder.is_absolute() else pipeline_dir / folder
    # the truth a dataset keeps beside a pair too: a report scores against it (keys follow its
    # content)
    try:
        paths = [
            p
            for _, l, r in pairs_for(params, folder)[0]
            for p in (l, r, truth_beside(l))
            if p is not None
        ]
    except NodeError:
        paths = []
    if params.truth:
        t = Path(params.truth).expanduser()
        paths.append(t if t.is_absolute() else pipeline_dir / t)
    return paths


def _pair_ids(params: FilesParams, ctx) -> list[str]:
    """The pair ids, from the file names alone (the engine reads the pairs one per call)."""
    return [pid for pid, _, _ in pairs_for(params, ctx.path(params.folder))[0]]


def _read_pair(params: FilesParams, pid: str, lp: Path, rp: Path, truth: dict, split: str) -> dict:
    """One pair; NodeError if it cannot be read."""
    kw = {"max_mpx": params.max_image_mpx, "expect_size": params.image_size_px}
    left, right = read_image(lp, **kw), read_image(rp, **kw)
    if left.shape != right.shape:
        raise NodeError(
            f"{lp.name} is {left.shape[1]}x{left.shape[0]} but {rp.name} is "
            f"{right.shape[1]}x{right.shape[0]}.",
            hint="both cameras must give the same size",
        )
    # a dataset's own ground-truth disparity (disp2.png for im2.png), for reports
    beside = truth_beside(lp)
    return {
        "id": pid,
        "left": left,
        "right": right,
        "truth": truth.get(pid),
        "split": split,
        "left_path": str(lp),
        "right_path": str(rp),
        "truth_disparity_path": str(beside) if beside else None,
    }


@node(
    "source.files",
    outputs={
        "pairs": Out("StereoPair", collection=True, description="Stereo pairs read from files.")
    },
    params=FilesParams,
    version="1",
    reads=_reads,
    items=_pair_ids,
)
def files(params: FilesParams, ctx=None) -> dict:
    """Read stereo pairs from a folder (left/right matched by name), with optional ground truth.

    In a run the engine reads the pairs one per call (``items=``), in the worker pool when there
    is one; a pair that cannot be read is skipped with a warning.
    """
    resolve = ctx.path if ctx is not None else (lambda v: Path(v).expanduser())
    pairs_list, rule = pairs_for(params, resolve(params.folder))
    per_item = ctx is not None and ctx.producing_items
    if (
        ctx is not None
        and not (per_item and ctx.item is not None)
        and rule.startswith("the dataset")
    ):
        # (said once: which convention applied)
        ctx.warn(f"{len(pairs_list)} pair(s) paired by {rule}")
    splits = None
    truth: dict[str, dict] = {}
    # the truth file decides the split (listed = train, or its split column); no random split
    if params.truth:
        truth, explicit = read_truth_file(resolve(params.truth))
        splits, warnings = truth_split(
            [pid for pid, _, _ in pairs_list], truth, explicit, resolve(params.truth)
        )
        if ctx is not None and not (per_item and ctx.item is not None):  # said once, not per pair
            for w in warnings:
                ctx.warn(w)
    # drawn for every pair, in order: a skipped pair leaves the others' split as it was
    draws = np.random.default_rng([params.seed, 3]).random(len(pairs_list))
    split_of = {
        pid: splits[pid] if splits else "train" if d < params.train_fraction else "test"
        for (pid, _, _), d in zip(pairs_list, draws)
    }
    if per_item and ctx.item is not None:
        found = [(pid, lp, rp) for pid, lp, rp in pairs_list if pid == ctx.item]
        if not found:
            ctx.warn(f"pair {ctx.item} skipped: its files are gone")
            return {}
        pid, lp, rp = found[0]
        try:
            return {"pairs": _read_pair(params, pid, lp, rp, truth, split_of[pid])}
        except NodeError as exc:  # one bad pair costs that pair only
            ctx.warn(f"pair {pid} skipped: {exc.message}")
            return {}
    if per_item:
        return {}
    out, skipped = {}, {}
    for k, (pid, lp, rp) in enumerate(pairs_list):
        if ctx is not None:
            ctx.progress(k, len(pairs_list), "pairs")
        try:
            out[pid] = _read_pair(params, pid, lp, rp, truth, split_of[pid])
        except NodeError as exc:  # one bad pair costs that pair only
            skipped[pid] = exc.message
            if ctx is not None:
                ctx.warn(f"pair {pid} skipped: {exc.message}")
    if not out:
        raise NodeError(
            f"none of the {len(pairs_list)} pairs could be read: "
            + "; ".join(f"{k}: {v}" for k, v in list(skipped.items())[:5]),
            hint="replace or remove the unreadable images",
        )
    return {"pairs": out}
