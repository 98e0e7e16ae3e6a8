"""Read back an artifact a run wrote (``<run>/<node>/<output>.json`` + ``.npz``), and check its rig.

A run writes every saved output as JSON, small arrays as nested lists and large ones into an
``.npz`` beside it (``{"npz": key, "shape", "dtype"}`` in the JSON). The loader nodes read that
back, check that the file holds the kind of artifact they expect, and -- when a calibration is
wired -- that it was made for the same rig: image size, focal length and baseline (a compensation
model or hand-eye fitted on another rig would move the arm to wrong places).

The rig fingerprint ``{"image_size": [w, h], "fx_px": float, "baseline_cm": float}`` is stored in
every ``CompensationModel``, ``HandEye`` and ``TableFrame`` fitted from located balls or a
calibration (key ``rig``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from stereograph.api import Field, NodeError, Params, PathField, data_file

__all__ = [
    "ArtifactLoadParams",
    "array_keys",
    "artifact_kind",
    "artifact_reads",
    "check_rig",
    "read_artifact",
    "resolve_path",
    "rig_fingerprint",
    "rig_from_file",
    "with_npz",
]


def _restore(v: Any, npz) -> Any:
    if isinstance(v, dict):
        if set(v) == {"npz", "shape", "dtype"} and isinstance(v["npz"], str):
            key = v["npz"].replace("/", "_")
            if npz is None or key not in npz:
                raise KeyError(v["npz"])
            return np.asarray(npz[key])
        return {k: _restore(x, npz) for k, x in v.items()}
    if isinstance(v, list):
        return [_restore(x, npz) for x in v]
    return v


# The most a file's arrays may take once decompressed. A run's arrays are a few MB (rectification
# maps of 4000x3000 cameras: ~200 MB); an .npz is a zip, and a few MB of zeros from someone else can
# decompress into tens of GB.
MAX_NPZ_BYTES = 2 << 30


def _check_npz_size(npz_path: Path, label: str) -> None:
    """Refuse an ``.npz`` whose arrays would take more than :data:`MAX_NPZ_BYTES` (its zip
    directory's sizes, read before anything is decompressed: a member cannot yield more than its
    recorded size)."""
    import zipfile

    try:
        with zipfile.ZipFile(npz_path) as zf:
            total = sum(i.file_size for i in zf.infolist())
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(exc) from None
    if total > MAX_NPZ_BYTES:
        raise NodeError(
            f"{label}: {npz_path} would decompress into {total / 2**30:.1f} GB of arrays, "
            "more than "
            f"the {MAX_NPZ_BYTES / 2**30:.0f} GB a run's file holds.",
            hint="give the .npz the run wrote beside the JSON (a file from someone else may be a "
            "decompression bomb)",
        )


def read_artifact(path: Path, label: str, kind: str, made_by: str) -> dict:
    """Load one artifact a run wrote as JSON (with its ``.npz`` when there is one).

    Parameters
    ----------
    path : Path
        The JSON file.
    label : str
        The loading node, for errors (``calibrator.load``).
    kind : str
        The artifact type expected, for errors (``CompensationModel``).
    made_by : str
        Which output writes such a file, for the hint (``<run>/fit/model.json``).

    Raises
    ------
    NodeError
        Missing or unreadable file, a per-item list, or a missing ``.npz``.
    """
    if not path.exists():
        raise NodeError(
            f"{label}: {path} does not exist.",
            hint=f"give the {kind} file a run wrote ({made_by}); relative paths start at the "
            "pipeline "
            "file's folder",
        )
    data_file(path, f"the {kind} file a run wrote ({made_by})", label)
    try:
        data = json.loads(path.read_text())
    # (nested deeper than Python's stack)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise NodeError(
            f"{label}: {path} is not a JSON file a run wrote ({exc}).",
            hint=f"give the {kind} file a run wrote ({made_by})",
        ) from None
    if not isinstance(data, dict):
        raise NodeError(
            f"{label}: {path} holds a list (a per-item output, such as locations), not a {kind}.",
            hint=f"give the {kind} file a run wrote ({made_by})",
        )
    npz_path = path.with_suffix(".npz")
    npz = None
    try:
        if npz_path.is_file():
            _check_npz_size(npz_path, label)
            with np.load(npz_path, allow_pickle=False) as z:
                npz = {k: z[k] for k in z.files}
        return _restore(data, npz)
    except KeyError as exc:
        raise NodeError(
            f"{label}: {path} refers to array {exc} in {npz_path}, which "
            f"{'lacks it' if npz is not None else 'does not exist'}.",
            hint="copy the .npz the run wrote beside the JSON together with it",
        ) from None
    except (OSError, ValueError) as exc:
        raise NodeError(
            f"{label}: cannot read {npz_path} ({exc}).",
            hint="copy the .npz the run wrote beside the JSON together with it",
        ) from None


def array_keys(art: dict, keys, source: str = "the file") -> dict:
    """Turn the nested lists of the named keys into float arrays (where present and not None);
    NodeError naming ``source`` and the key for one that is not a table of numbers."""
    for k in keys:
        if art.get(k) is not None:
            try:
                art[k] = np.asarray(art[k], dtype=float)
            except (TypeError, ValueError) as exc:
                raise NodeError(
                    f"{source}: `{k}` is not a matrix of numbers ({str(exc).split('.')[0]}).",
                    hint="give the file as the run wrote it",
                ) from None
    return art


def rig_fingerprint(calibration: dict | None) -> dict | None:
    """``{"image_size", "fx_px", "baseline_cm"}`` of a StereoCalibration or Rectification (None if
    unknown)."""
    if not calibration or calibration.get("K1") is None or calibration.get("image_size") is None:
        return None
    # a Rectification may be rescaled
    size = calibration.get("source_size") or calibration["image_size"]
    if calibration.get("T_cm") is not None:
        baseline = float(np.linalg.norm(np.asarray(calibration["T_cm"], float)))
    elif calibration.get("baseline_cm") is not None:
        baseline = abs(float(calibration["baseline_cm"]))
    else:
        return None
    return {
        "image_size": [int(v) for v in size],
        "fx_px": float(np.asarray(calibration["K1"], float)[0, 0]),
        "baseline_cm": baseline,
    }


def rig_from_file(calibration: dict) -> str:
    """Where a calibration came from, for messages."""
    return str(
        calibration.get("source_file")
        or f"the wired calibration ({calibration.get('method', '?')})"
    )


def check_rig(
    label: str, rig: dict | None, path: Path, calibration: dict | None, tolerance: float, warn=None
) -> None:
    """Refuse an artifact made for another rig than ``calibration``; both files are named.

    Parameters
    ----------
    rig : dict or None
        The artifact's stored fingerprint (None: made before fingerprints existed -> a warning).
    tolerance : float
        Largest relative difference of focal length and baseline (unitless).
    """
    if calibration is None:
        return
    now = rig_fingerprint(calibration)
    if rig is None or now is None:
        if warn is not None:
            warn(
                f"{path} records no rig (image size, focal length, baseline): not checked against "
                f"{rig_from_file(calibration)}"
            )
        return
    try:  # (the file's own record: it may be damaged)
        size = [int(v) for v in rig["image_size"]]
        stored = {key: float(rig[key]) for key in ("fx_px", "baseline_cm")}
    except (KeyError, TypeError, ValueError, OverflowError):
        size, stored = [], {}
    if len(size) != 2 or len(stored) != 2 or not all(np.isfinite(list(stored.values()))):
        raise NodeError(
            f"{label}: {path} records its rig (image_size, fx_px, baseline_cm) in a form "
            "a run does "
            "not write.",
            hint="give the file as the run wrote it, or fit it again",
        )
    problems = []
    if size != now["image_size"]:
        problems.append(
            f"image size {size[0]}x{size[1]} vs {now['image_size'][0]}x{now['image_size'][1]} px"
        )
    for key, name, unit in (("fx_px", "focal length", "px"), ("baseline_cm", "baseline", "cm")):
        a, b = stored[key], now[key]
        if abs(a - b) > tolerance * abs(b):
            problems.append(f"{name} {a:.4g} vs {b:.4g} {unit} ({100 * (a / b - 1):+.2f} %)")
    if problems:
        raise NodeError(
            f"{label}: {path} was made for another rig than {rig_from_file(calibration)}: "
            + "; ".join(problems)
            + ".",
            hint="use the calibration it was fitted with, or fit it again with this calibration "
            f"(rig_tolerance {tolerance:g} allows relative differences up to that)",
        )


def artifact_kind(art: dict) -> str:
    """Best guess of which artifact type a loaded JSON holds (for "wrong kind of file" errors)."""
    if not isinstance(art, dict):
        return "a list"
    if "K1" in art and "T_cm" in art:
        return "a StereoCalibration"
    if "coefficients" in art and "type" in art:
        return "a CompensationModel"
    if "T_base_from_left" in art:
        return "a HandEye"
    if "T_table_from_left" in art:
        return "a TableFrame"
    if "joints" in art and "reach_cm" in art:
        return "an ArmModel"
    return "no artifact this loader knows (keys: " + ", ".join(sorted(art)[:8]) + ")"


def resolve_path(value: str, pipeline_dir: Path) -> Path:
    """A path from YAML, relative to the pipeline's folder."""
    p = Path(value).expanduser()
    return p if p.is_absolute() else pipeline_dir / p


def with_npz(paths: list[Path]) -> list[Path]:
    """The paths, each ``.json`` followed by its ``.npz`` where one lies beside it (for a node's
    ``reads``)."""
    out = []
    for p in paths:
        out.append(p)
        if p.suffix.lower() == ".json" and p.with_suffix(".npz").is_file():
            out.append(p.with_suffix(".npz"))
    return out


class ArtifactLoadParams(Params):
    """Parameters of a node that loads one artifact a run wrote (``*.load``)."""

    path: str = PathField(
        ...,
        description="The JSON file a run wrote for this output, relative to the pipeline file "
        "(its .npz, if any, beside it).",
    )
    rig_tolerance: float = Field(
        0.01,
        gt=0,
        le=0.5,
        description="Largest relative difference of focal length and baseline between the "
        "file's rig and the wired calibration (unitless; 0.01 = 1 %).",
    )


def artifact_reads(params: ArtifactLoadParams, pipeline_dir: Path) -> list[Path]:
    """The files an artifact loader reads (its ``reads=``): the JSON and its ``.npz``."""
    return with_npz([resolve_path(params.path, pipeline_dir)])
