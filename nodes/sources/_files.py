"""File helpers shared by the file sources: list matched left/right images, read them with clear
errors."""

from __future__ import annotations

import re
from glob import escape as glob_escape
from pathlib import Path

import cv2
import numpy as np

from stereograph.api import NodeError

__all__ = [
    "DEFAULT_GLOBS",
    "DEFAULT_MAX_MPX",
    "IMAGE_SUFFIXES",
    "PAIRING_DOC",
    "find_pairs",
    "header_size",
    "list_pairs",
    "pair_key",
    "pairs_for",
    "read_image",
    "truth_beside",
]

# megapixels: above any stereo camera this project targets, far below a decompression bomb
DEFAULT_MAX_MPX = 50.0

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"}
_SIDE = re.compile(r"(?i)(left|right|(?<![a-z])[lr](?![a-z]))")
# Middlebury-style camelCase names (aloeL.jpg / aloeR.jpg): a capital L or R ending the stem.
_SIDE_SUFFIX = re.compile(r"(?<=[a-z0-9])[LR]$")


def pair_key(stem: str) -> str:
    """The name a left and a right image share: the stem without its side token (left/right/L/R)."""
    key, n = _SIDE.subn("", stem, count=1)
    if n == 0:
        key = _SIDE_SUFFIX.sub("", stem)
    return key.strip("_-. ")


def _glob(base: Path, pattern: str) -> list[Path]:
    p = Path(pattern).expanduser()
    if p.is_absolute():
        files = sorted(Path(p.anchor).glob(str(p.relative_to(p.anchor))))
    else:
        files = sorted(base.glob(pattern))
    return [f for f in files if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES]


DEFAULT_GLOBS = ("*left*", "*right*")
# : Datasets' own names for one pair in a folder: Middlebury 2014+ (im0 / im1), 2001-2003 (im2 /
# im6),
#: 2005-2006 (view1 / view5). The pair is named by its folder (the scene).
DATASET_NAMES = [("im0", "im1"), ("im2", "im6"), ("view1", "view5")]
#: A dataset's ground-truth disparity of the left image, beside it: Middlebury 2014+ (disp0GT.pfm or
#: disp0.pfm), 2001-2003 (disp2.png), 2005-2006 (disp1.png).
DATASET_TRUTH = {
    "im0": ("disp0GT.pfm", "disp0.pfm"),
    "im2": ("disp2.png", "disp2.pgm"),
    "view1": ("disp1.png",),
}
#: Folder pairs that hold the left and the right images under the same names: ours, KITTI's grey and
#: colour cameras, EuRoC's (cam0/data/).
DATASET_FOLDERS = [
    ("left", "right"),
    ("image_0", "image_1"),
    ("image_2", "image_3"),
    ("cam0/data", "cam1/data"),
    ("cam0", "cam1"),
]
#: The ``pairing`` param of the file sources, described once.
PAIRING_DOC = (
    "auto: names with left/right (or L/R), else a dataset's own names (im0/im1, im2/im6, "
    "view1/view5: "
    "one pair named by its folder), else folders (left/ right/, image_0/ image_1/, cam0/ "
    "cam1/); globs: "
    "left_glob / right_glob only."
)


def find_pairs(
    folder: Path,
    left_glob: str = DEFAULT_GLOBS[0],
    right_glob: str = DEFAULT_GLOBS[1],
    pairing: str = "auto",
) -> tuple[list[tuple[str, Path, Path]], str]:
    """``(pairs, rule)``: the pairs of a folder, and in words the rule that paired them.

    ``pairing: globs`` (or globs other than the defaults) uses the globs alone. ``auto`` tries, in
    order: names holding left / right, names ending in L / R (aloeL.jpg), a dataset's own names for
    one pair (:data:`DATASET_NAMES`, named by the folder), then left and right folders
    (:data:`DATASET_FOLDERS`); NodeError naming what was tried if none fits.
    """
    if pairing == "globs" or (left_glob, right_glob) != DEFAULT_GLOBS:
        return list_pairs(folder, left_glob, right_glob), f"the globs {left_glob} / {right_glob}"
    try:
        return list_pairs(folder, left_glob, right_glob), "names with left / right"
    except NodeError as first:
        if not folder.is_dir():
            raise
        try:  # aloeL.jpg / aloeR.jpg: a capital L or R ending the name
            return list_pairs(folder, "*L.*", "*R.*"), "names ending in L / R"
        except NodeError:
            pass
        for left, right in DATASET_NAMES:
            lf, rf = _glob(folder, f"{left}.*"), _glob(folder, f"{right}.*")
            if len(lf) == 1 and len(rf) == 1:
                return [
                    (_clean_id(folder.resolve().name), lf[0], rf[0])
                ], f"the dataset names {left} / {right}"
        for left, right in DATASET_FOLDERS:
            if _glob(folder, f"{left}/*") and _glob(folder, f"{right}/*"):
                return list_pairs(
                    folder, f"{left}/*", f"{right}/*"
                ), f"the folders {left}/ and {right}/"
        tried = ", ".join(f"{a}/{b}" for a, b in DATASET_NAMES + DATASET_FOLDERS)
        raise NodeError(
            first.message,
            hint=f"{first.hint}; also tried the dataset conventions {tried}. Or set "
            "pairing: globs with left_glob / right_glob",
        ) from None


def truth_beside(left: Path) -> Path | None:
    """The ground-truth disparity a dataset keeps beside a left image, or None.

    :data:`DATASET_TRUTH` for the datasets' own names; otherwise ``<key>GT.*`` (Middlebury as
    OpenCV ships it: aloeL.jpg -> aloeGT.png), with ``<key>`` the name without its side token.
    """
    if left.stem in DATASET_TRUTH:
        found = [left.parent / n for n in DATASET_TRUTH[left.stem]]
    else:
        key = pair_key(left.stem)
        found = sorted(left.parent.glob(f"{glob_escape(key)}GT.*")) if key else []
    found = [p for p in found if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES | {".pfm"}]
    return found[0] if found else None


def pairs_for(params, folder: Path) -> tuple[list[tuple[str, Path, Path]], str]:
    """:func:`find_pairs` with a source's ``left_glob``, ``right_glob`` and ``pairing`` params."""
    return find_pairs(folder, params.left_glob, params.right_glob, params.pairing)


def list_pairs(folder: Path, left_glob: str, right_glob: str) -> list[tuple[str, Path, Path]]:
    """Match left and right images by name.

    Parameters
    ----------
    folder : Path
        Base folder for relative globs.
    left_glob, right_glob : str
        Glob patterns (relative to ``folder`` or absolute), e.g. ``left*.jpg``
        or ``left/*.png``.

    Returns
    -------
    list of (pair_id, left_path, right_path), sorted by id.

    Raises
    ------
    NodeError
        No images, unequal counts, or names that do not pair up (the files are named).
    """
    if not folder.exists():
        raise NodeError(
            f"image folder {folder} does not exist.",
            hint="fix the `folder` parameter (relative paths start at the pipeline file's folder)",
        )
    lefts, rights = _glob(folder, left_glob), _glob(folder, right_glob)
    if not lefts and not rights:
        raise NodeError(
            f"no images match {left_glob!r} / {right_glob!r} in {folder}.",
            hint=_no_images_hint(folder),
        )
    if len(lefts) != len(rights):
        lk = {pair_key(p.stem) for p in lefts}
        rk = {pair_key(p.stem) for p in rights}
        extra = [p.name for p in lefts if pair_key(p.stem) not in rk] + [
            p.name for p in rights if pair_key(p.stem) not in lk
        ]
        raise NodeError(
            f"{len(lefts)} left but {len(rights)} right images in {folder}; unmatched: "
            f"{', '.join(extra) or '(names collide)'}.",
            hint="every left image needs a right image of the same name (left01.jpg / right01.jpg)",
        )

    if _separate_dirs(lefts, rights) and {p.name for p in lefts} == {p.name for p in rights}:
        # left/x.png <-> right/x.png
        kl, kr = {p.stem: p for p in lefts}, {p.stem: p for p in rights}
    else:
        kl, kr = {pair_key(p.stem): p for p in lefts}, {pair_key(p.stem): p for p in rights}
    if len(kl) != len(lefts) or len(kr) != len(rights):
        raise NodeError(
            f"image names in {folder} do not give unique pair names once left/right is removed.",
            hint="name pairs like left01.png / right01.png or put them in left/ and right/ folders",
        )
    missing = sorted(set(kl) ^ set(kr))
    # no side token in the names (cam0_01.png / cam1_01.png): what the globs' wildcards matched
    if missing:
        gl, gr = _glob_keys(lefts, left_glob), _glob_keys(rights, right_glob)
        if gl is not None and gr is not None and len(set(gl) ^ set(gr)) < len(missing):
            kl, kr, missing = gl, gr, sorted(set(gl) ^ set(gr))
    if missing:
        names = [kl[k].name if k in kl else kr[k].name for k in missing]
        raise NodeError(
            f"these images have no partner: {', '.join(names)} (in {folder}).",
            hint="every left image needs a right image of the same name",
        )
    return [(_clean_id(k), kl[k], kr[k]) for k in sorted(kl)]


def _no_images_hint(folder: Path) -> str:
    """How to fix globs that match nothing: globs for the side-named images the folder holds,
    or what it holds."""
    images = (
        [p.name for p in sorted(folder.iterdir())[:2000] if p.suffix.lower() in IMAGE_SUFFIXES]
        if folder.is_dir()
        else []
    )
    sided = [n for n in images if "left" in n.lower()]
    hint = (
        f"the folder holds {len(images)} images named like {sided[0]!r}: set left_glob: "
        f"'{_side_glob(images, 'left')}' and right_glob: "
        f"'{_side_glob(images, 'right')}' (or globs of your "
        "own)"
        if sided
        else f"the folder holds {len(images)} images "
        f"({', '.join(images[:3])}{' ...' if len(images) > 3 else ''}): "
        "fix the globs"
        if images
        else f"put images ({', '.join(sorted(IMAGE_SUFFIXES))}) there or fix the globs"
    )
    return hint


def _glob_keys(files: list[Path], pattern: str) -> dict[str, Path] | None:
    """{the part of each file name the glob's wildcards matched: file}, or None if not unique."""
    name = Path(pattern).name
    wild = [i for i, ch in enumerate(name) if ch in "*?["]
    if not wild:
        return None
    prefix, suffix = (
        name[: wild[0]],
        name[max(name.rfind("*"), name.rfind("?"), name.rfind("]")) + 1 :],
    )
    keys = {}
    for f in files:
        n = f.name
        if not (n.startswith(prefix) and n.endswith(suffix)) or len(n) < len(prefix) + len(suffix):
            return None
        core = n[len(prefix) : len(n) - len(suffix)]
        core = core[: -len(f.suffix)] if f.suffix and core.endswith(f.suffix) else core
        keys[core.strip("_-. ")] = f
    return keys if len(keys) == len(files) and "" not in keys else None


def _side_glob(names: list[str], side: str) -> str:
    """``*left*`` spelt as the file names spell it (``*Left*``, ``*LEFT*``): globs are
    case-sensitive."""
    spelt = next(
        (n[i : i + len(side)] for n in names for i in [n.lower().find(side)] if i >= 0), side
    )
    return f"*{spelt}*"


def _separate_dirs(lefts, rights) -> bool:
    return {p.parent for p in lefts}.isdisjoint({p.parent for p in rights})


def _clean_id(key: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", key) or "pair"


def header_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from the image file's header, without decoding the pixels; None if the
    header is not one Pillow knows (OpenCV may still read the file)."""
    from PIL import Image

    # our limit applies; Pillow's would hide the size
    before, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with Image.open(path) as im:  # reads the header only
            return int(im.size[0]), int(im.size[1])
    except Exception:  # not an image Pillow knows, truncated header, ...: let OpenCV judge
        return None
    finally:
        Image.MAX_IMAGE_PIXELS = before


def read_image(
    path: Path,
    color: bool = True,
    max_mpx: float = DEFAULT_MAX_MPX,
    expect_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """Read an image as uint8 BGR (``color``) or as stored (grey stays grey).

    The size is checked from the header before decoding: a 20000x20000 PNG is a few hundred KB on
    disk but gigabytes decoded. ``expect_size`` (width, height), e.g. the calibration's, refuses
    any other size the same way.

    Raises
    ------
    NodeError
        The file cannot be read, is not an image, is larger than ``max_mpx`` megapixels, or is
        not ``expect_size``.
    """
    size = header_size(path) if path.is_file() else None
    if size is not None and size[0] * size[1] > max_mpx * 1e6:
        raise NodeError(
            f"image {path} is {size[0]}x{size[1]} ({size[0] * size[1] / 1e6:.0f} Mpx), above the "
            f"limit of {max_mpx:g} Mpx; it was not decoded.",
            hint="use images of the cameras' resolution, or raise max_image_mpx if they really are "
            "that large",
        )
    if size is not None and expect_size is not None and tuple(size) != tuple(expect_size):
        raise NodeError(
            f"image {path} is {size[0]}x{size[1]}, not the expected "
            f"{expect_size[0]}x{expect_size[1]}; "
            "it was not decoded.",
            hint="use images from the calibrated cameras at their resolution, or fix image_size_px",
        )
    try:
        data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
        flag = cv2.IMREAD_COLOR if color else cv2.IMREAD_UNCHANGED
        img = cv2.imdecode(data, flag) if data is not None and data.size else None
    except (cv2.error, OSError, MemoryError) as exc:
        raise NodeError(
            f"cannot read image {path}: "
            f"{str(exc).strip().splitlines()[-1] if str(exc) else exc!r}.",
            hint="replace or remove the file",
        ) from None
    if img is None:
        raise NodeError(
            f"cannot read image {path}: not a readable image file.",
            hint="replace or remove the file (supported: png, jpg, bmp, tif, pgm, ppm, webp)",
        )
    if img.shape[0] * img.shape[1] > max_mpx * 1e6:  # a format whose header Pillow did not read
        raise NodeError(
            f"image {path} is {img.shape[1]}x{img.shape[0]}, above the limit of {max_mpx:g} Mpx.",
            hint="use images of the cameras' resolution, or raise max_image_mpx",
        )
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img
