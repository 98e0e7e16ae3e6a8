"""Values to files and back: plain data with arrays (:func:`encode`, :func:`decode`), a value's
content key (:func:`content_key`), 8-bit images as PNG and pictures for people as JPEG
(:func:`jpeg_roundtrip`, :func:`entry_blobs`).

A lossy output's readers all get the decoded JPEG, and writing that array again writes the very
bytes it came from. Public: the functions above, :func:`png_decode`, :func:`read_written_image`,
:data:`JPEG_QUALITY`.
"""

from __future__ import annotations

import hashlib
import io
import json
import time
import weakref
from pathlib import Path
from typing import Any

import numpy as np


def is_png_image(a: Any) -> bool:
    """An 8-bit image PNG holds exactly (HxW, HxWx3, HxWx4 ``uint8``, not tiny)."""
    return (
        isinstance(a, np.ndarray)
        and a.dtype == np.uint8
        and a.size > 64
        and (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4)))
    )


def _png_encode(a: np.ndarray) -> bytes | None:
    """PNG bytes (OpenCV's default level: fast, lossless), byte-identical to what the run folder
    gets."""
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(a))
    return buf.tobytes() if ok else None


JPEG_QUALITY = 90  # a picture for people (Out(lossy=True)): no visible loss, ~6x smaller than PNG


# id(decoded image) -> (a weak reference to it, the JPEG bytes it was decoded from): writing a lossy
# output that is already a decoded JPEG writes those very bytes, not a second generation (which
# differs by up to 32 grey levels), so the run folder's file decodes to the array its readers got.
_DECODED_FROM: dict[int, tuple[Any, bytes]] = {}


def jpeg_roundtrip(a: Any) -> tuple[bytes, np.ndarray] | None:
    """The JPEG bytes of an 8-bit image (HxW or HxWx3) and the image they decode to -- the value
    every reader of a lossy output gets (OpenCV's decoder is deterministic); None for other values.
    An image this function decoded gives back its own bytes and itself."""
    import cv2

    if not is_png_image(a) or (a.ndim == 3 and a.shape[2] != 3):
        return None
    known = _DECODED_FROM.get(id(a))
    if known is not None and known[0]() is a:
        return known[1], a
    ok, buf = cv2.imencode(
        ".jpg", np.ascontiguousarray(a), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
    )
    if not ok:
        return None
    data = buf.tobytes()
    decoded = png_decode(data)
    key = id(decoded)
    _DECODED_FROM[key] = (weakref.ref(decoded, lambda _r, k=key: _DECODED_FROM.pop(k, None)), data)
    return data, decoded


def png_decode(data: bytes) -> np.ndarray:
    import cv2

    a = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if a is None or a.dtype != np.uint8:
        raise ValueError("an image file of the entry does not decode")
    return a


def read_written_image(files: list[Path]) -> np.ndarray | None:
    """An item's image as the run folder holds it (its PNG, else its JPEG); None if unreadable.

    PNG is lossless (the very array); a lossy output's JPEG decodes to the very array too, since
    every reader of a lossy output gets the decoded JPEG."""
    import cv2

    png = next((f for f in files if f.suffix == ".png"), None)
    path = png or next((f for f in files if f.suffix == ".jpg"), None)
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path is not None else None


def encode(value: Any, arrays: dict[str, np.ndarray], where: str = "value") -> Any:
    """Replace arrays by references, check the rest is plain JSON data."""
    if isinstance(value, np.ndarray):
        name = f"a{len(arrays)}"
        arrays[name] = value
        return {"__ndarray__": name}
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (list, tuple)):
        return [encode(v, arrays, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise TypeError(f"{where} has a non-string key {k!r}")
            out[k] = encode(v, arrays, f"{where}.{k}")
        return out
    raise TypeError(
        f"{where} is a {type(value).__name__}, not plain data "
        "(dict/list/str/number/bool/None/ndarray)"
    )


def decode(value: Any, arrays: Any) -> Any:
    if isinstance(value, dict):
        if len(value) == 1 and "__ndarray__" in value:
            return arrays[value["__ndarray__"]]
        return {k: decode(v, arrays) for k, v in value.items()}
    if isinstance(value, list):
        return [decode(v, arrays) for v in value]
    return value


def content_key(value: Any) -> str:
    """Digest of a plain-data value's content (arrays by dtype, shape and bytes)."""
    arrays: dict[str, np.ndarray] = {}
    tree = encode(value, arrays)
    h = hashlib.blake2b(json.dumps(tree, sort_keys=True, allow_nan=True).encode(), digest_size=16)
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}{a.dtype.str}{a.shape}".encode())
        h.update(a.data)
    return "c" + h.hexdigest()


def entry_blobs(
    tree: Any, arrays: dict[str, np.ndarray], encoded: dict[str, bytes]
) -> tuple[dict[str, bytes], dict[str, str], float]:
    """``(blobs, png_outputs, codec_seconds)``: an entry's files -- data.json, 8-bit images as PNG
    (lossless, 3-10x smaller than raw) or the JPEG bytes given, the other arrays in one npz -- and
    which top-level output each image file is (the run folder copies it as it is)."""
    blobs = {"data.json": json.dumps(tree, allow_nan=True).encode()}
    outs = tree.items() if isinstance(tree, dict) else ()
    refs = {
        out: ref["__ndarray__"]
        for out, ref in outs
        if isinstance(ref, dict) and ref.get("__ndarray__")
    }
    for out, name in refs.items():
        if out in encoded and name in arrays:
            blobs[f"{name}.jpg"] = encoded[out]
            del arrays[name]
    t0 = time.perf_counter()
    for name in [n for n, a in arrays.items() if is_png_image(a)]:
        png = _png_encode(arrays[name])
        if png is not None:
            blobs[f"{name}.png"] = png
            del arrays[name]
    codec_seconds = time.perf_counter() - t0
    ready = {
        out: f"{name}{ext}"
        for out, name in refs.items()
        for ext in (".png", ".jpg")
        if f"{name}{ext}" in blobs
    }
    if arrays:
        buf = io.BytesIO()
        # masks (bool) are mostly runs of one value: zlib makes them ~50x smaller, fast;
        # float arrays barely compress, so they are stored as they are
        bools = any(a.dtype == np.bool_ for a in arrays.values())
        (np.savez_compressed if bools else np.savez)(buf, **arrays)
        blobs["arrays.npz"] = buf.getvalue()
    return blobs, ready, codec_seconds
