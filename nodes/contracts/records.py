"""Shape checks of the records the kinds hand each other, registered with the engine
(:func:`stereograph.api.artifact_check`): a node that returns a value of the wrong shape fails
itself, naming its output, instead of the next node failing on a malformed input.

Only what every producer guarantees is checked (docs/artifacts.md): a per-item result record
says whether the object was ``found``; a pair holds its ``left`` and ``right`` images; an image is
an array of rows and columns (and channels).
"""

from __future__ import annotations

from typing import Any

from stereograph.core.checks import artifact_check  # (stereograph.api's, without pydantic)


def _found_record(value: Any) -> str | None:
    if not isinstance(value, dict):
        return f"got a {type(value).__name__}, not a record (a dict)"
    if "found" not in value:
        return (
            f"a record without 'found' (keys: {', '.join(sorted(map(str, value))[:8]) or 'none'})"
        )
    return None


def _pair(value: Any) -> str | None:
    if not isinstance(value, dict):
        return f"got a {type(value).__name__}, not a pair (a dict with 'left' and 'right')"
    missing = [k for k in ("left", "right") if value.get(k) is None]
    return f"a pair without {' and '.join(repr(k) for k in missing)}" if missing else None


def _image(value: Any) -> str | None:
    shape = getattr(value, "shape", None)
    if shape is None or not hasattr(value, "dtype"):
        return f"got a {type(value).__name__}, not an image (an array H x W or H x W x channels)"
    if len(shape) not in (2, 3) or (len(shape) == 3 and shape[2] not in (1, 3, 4)):
        return f"an array of shape {tuple(shape)}, not H x W or H x W x 1/3/4"
    return None


for _type in ("Segmentation", "Disparity", "Location"):
    artifact_check(_type)(_found_record)
for _type in ("StereoPair", "RectifiedPair"):
    artifact_check(_type)(_pair)
artifact_check("Image")(_image)
