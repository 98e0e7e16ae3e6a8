"""Values into files, in open formats: each write whole or absent (:func:`write_whole`).

Images as PNG (JPEG when lossy), other values as JSON (large arrays in ``.npz``), per-item
outputs as one JSON list or a folder of images, file values as the file itself. An image
rendered for a cached entry is reused (linked or copied) by a later run. What goes where in a
run's folder: :mod:`stereograph.core.run_folder`; the formats: docs/engine.md.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import re
import shutil
import sys
import urllib.parse
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereograph.core.run_result import is_lasting_key

if TYPE_CHECKING:
    import numpy as np

SMALL_ARRAY = 4096  # elements; larger arrays go to .npz beside the JSON
_PLAIN_ID = re.compile(r"^[^\W][\w.-]{0,119}$")


def file_name(item: Any) -> str:
    """An item id as one safe file-name component.

    Item ids come from data (a file name, a scene id in a YAML list), so ``../../x`` or ``/etc``
    must not become a path: ids of letters, digits, ``_ . -`` (not starting with a dot, at most
    120 characters) are kept as they are; any other is percent-encoded (``..%2F..%2Fx``), and a
    long one shortened with a digest. Distinct ids give distinct names.
    """
    text = str(item)
    if _PLAIN_ID.match(text) and ".." not in text:
        return text
    enc = urllib.parse.quote(text, safe="-_").replace(".", "%2E")
    if len(enc) > 120:
        enc = (
            enc[:96]
            + "~"
            + hashlib.blake2b(text.encode("utf-8", "surrogatepass"), digest_size=8).hexdigest()
        )
    return enc or "%00"


def _numpy() -> Any:
    """NumPy if something imported it, else None: then no value is an array (a replayed rerun writes
    its run folder without importing NumPy)."""
    return sys.modules.get("numpy")


def image_shaped(v: Any, channels: tuple[int, ...] = (3, 4)) -> bool:
    """A uint8 array H x W, or H x W x C with C in ``channels``, of any size."""
    np = _numpy()
    return np is not None and (
        isinstance(v, np.ndarray)
        and v.dtype == np.uint8
        and (v.ndim == 2 or (v.ndim == 3 and v.shape[2] in channels))
    )


def is_image(v: Any) -> bool:
    """An image written as PNG (:func:`image_shaped`, more than 64 values: smaller ones are
    data)."""
    return image_shaped(v) and v.size > 64


_SUFFIX = re.compile(r"^\.[A-Za-z0-9]{1,10}$")


def is_file_value(v: Any) -> bool:
    """A node-encoded file: ``{"file_suffix": ".ext", "file_bytes": uint8 1-D array | "file_text":
    str, ...}``."""
    if not (
        isinstance(v, dict)
        and isinstance(v.get("file_suffix"), str)
        and _SUFFIX.match(v["file_suffix"])
    ):
        return False
    np = _numpy()
    content = v.get("file_bytes")
    if np is not None and isinstance(content, np.ndarray):
        return content.ndim == 1 and content.dtype == np.uint8
    return isinstance(v.get("file_text"), str)


def file_content(v: dict) -> bytes:
    """The bytes of a file value (text is written as UTF-8)."""
    return v["file_bytes"].tobytes() if "file_bytes" in v else v["file_text"].encode()


def to_json(v: Any, big: dict[str, np.ndarray], path: str = "") -> Any:
    if v is None or type(v) in _PLAIN:  # most leaves: no NumPy type to ask about
        return v
    np = _numpy()
    if np is not None:
        if isinstance(v, np.ndarray):
            if v.size <= SMALL_ARRAY:
                return v.tolist()
            big[path or "array"] = v
            return {"npz": path or "array", "shape": list(v.shape), "dtype": str(v.dtype)}
        if isinstance(v, (np.floating, np.integer, np.bool_)):
            return v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else (1e308 if v > 0 else -1e308)
    if isinstance(v, dict):
        return {str(k): to_json(x, big, f"{path}.{k}" if path else str(k)) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_json(x, big, f"{path}[{i}]") for i, x in enumerate(v)]
    return v


_PLAIN = (str, int, bool)


def _with_ext(stem: Path, ext: str) -> Path:
    """``stem`` + ``ext`` (not ``with_suffix``: an item id ``scene.001`` keeps its ``.001``)."""
    return stem.with_name(stem.name + ext)


def write_whole(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file beside it: the file is whole or absent
    (an interrupt, a full disk), and no ``.tmp`` is left behind."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)  # never a half-written result file
    except BaseException:
        tmp.unlink(missing_ok=True)  # a full disk must not leave a .tmp behind
        raise


def write_value(path_stem: Path, value: Any, lossy: bool = False) -> list[Path]:
    """Write one value as PNG or JSON (+ .npz for large arrays); returns the files written.
    ``lossy``: an image output declared ``Out(lossy=True)`` (a picture for people) is written as
    JPEG. ``None`` is an output the node did not produce (an overlay switched off): nothing is
    written."""
    if value is None:
        return []
    if lossy:
        from stereograph.core.codecs import jpeg_roundtrip

        jpeg = jpeg_roundtrip(value)
        if jpeg is not None:
            p = _with_ext(path_stem, ".jpg")
            write_whole(p, jpeg[0])
            return [p]
    if is_file_value(value):
        p = path_stem.with_suffix(value["file_suffix"])
        write_whole(p, file_content(value))
        return [p]
    if is_image(value):
        import cv2

        ok, buf = cv2.imencode(".png", value)
        if ok:
            p = _with_ext(path_stem, ".png")
            write_whole(p, buf.tobytes())
            return [p]
    big: dict[str, np.ndarray] = {}
    data = to_json(value, big)
    files = []
    p = _with_ext(path_stem, ".json")
    write_whole(p, json.dumps(data, indent=1).encode())
    files.append(p)
    if big:  # (arrays: NumPy is imported)
        import numpy as np

        buf = io.BytesIO()
        np.savez_compressed(buf, **{k.replace("/", "_"): a for k, a in big.items()})
        q = _with_ext(path_stem, ".npz")
        write_whole(q, buf.getvalue())
        files.append(q)
    return files


def write_collection(stem: Path, items: dict[str, Any], lossy: bool = False) -> list[Path]:
    """Write a per-item output: a folder of PNG images (JPEG for a ``lossy`` output), or one JSON
    list of records. Items whose value is ``None`` (not produced) are left out; none produced, no
    file."""
    if not items:
        return write_value(stem, [])
    items = {i: v for i, v in items.items() if v is not None}
    if not items:
        return []
    first = next(iter(items.values()))
    if is_image(first) or is_file_value(first):
        out = []
        for i, v in items.items():
            out += write_value(stem / file_name(i), v, lossy)
        return out
    records = []
    for i, v in items.items():
        records.append({"item": i, **v} if isinstance(v, dict) else {"item": i, "value": v})
    return write_value(stem, records)


def _rendered(store: Any, key: str | None, output: str, stem: Path, produce: Any) -> list[Path]:
    """Write one output, reusing the files rendered for the same artifact on an earlier run.

    Encoding a cached image again is most of a cached run's time; a copy of the PNG is not.
    """
    if store is None or not key or not is_lasting_key(key):
        return produce()
    ready = store.ready_file(key, output)
    # the entry keeps this image as the very PNG (or JPEG) the run folder gets
    if ready is not None:
        dest = _with_ext(stem, ready.suffix)
        link_or_copy(ready, dest)
        return [dest]
    rdir = store.root / "rendered" / key[:2] / f"{key}-{output}"
    blobs = _verified_render(rdir)
    if blobs:
        files = []
        for name, data in blobs.items():
            dest = _with_ext(stem, Path(name).suffix)
            write_whole(dest, data)
            files.append(dest)
        return files
    if rdir.exists() and store.writable:  # corrupt or unverifiable: render again
        shutil.rmtree(rdir, ignore_errors=True)
    files = produce()
    if not store.writable or store.ready_file(key, output):
        return files  # (an entry stored just now keeps the PNG itself: no second copy)
    tmp = store.tmp / f"r-{uuid.uuid4().hex}"
    try:
        tmp.mkdir(parents=True, exist_ok=True)
        digests = {}
        for f in files:
            data = f.read_bytes()
            (tmp / f.name).write_bytes(data)
            digests[f.name] = hashlib.blake2b(data, digest_size=16).hexdigest()
        (tmp / RENDER_DIGESTS).write_text(json.dumps(digests))  # last: marks the copy complete
        rdir.parent.mkdir(parents=True, exist_ok=True)
        os.rename(tmp, rdir)
    except OSError:
        # another run rendered it first, or the cache cannot take it: the result is written anyway
        pass
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return files


def link_or_copy(src: Path, dest: Path) -> None:
    """Put ``src`` at ``dest`` as a hard link (no second copy on disk), else as a copy (another
    disk).

    The cache checks its files' digests before any use, so a linked result edited in place is
    detected there, and recomputed, never delivered."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        os.link(src, tmp)
        os.replace(tmp, dest)
    except OSError:
        tmp.unlink(missing_ok=True)
        write_whole(dest, src.read_bytes())


RENDER_DIGESTS = "digests.json"


def _verified_render(rdir: Path) -> dict[str, bytes] | None:
    """The rendered files kept in ``rdir`` if every one matches its recorded digest, else None
    (a flipped byte in a cached PNG must not be delivered as a result)."""
    try:
        digests = json.loads((rdir / RENDER_DIGESTS).read_text())
        if not isinstance(digests, dict) or not digests:
            return None
        blobs = {}
        for name, want in sorted(digests.items()):
            if "/" in name or name.startswith("."):
                return None
            data = (rdir / name).read_bytes()
            if hashlib.blake2b(data, digest_size=16).hexdigest() != want:
                return None
            blobs[name] = data
        return blobs
    except (OSError, ValueError, TypeError, AttributeError):
        return None


def image_per_item(run: Any, first: tuple) -> bool:
    """Whether a per-item output goes to the run folder as one image file per item: known from
    its first entry's manifest without loading it, else from the first item's value."""
    if run.store is not None and run.store.ready_file(run.key_of(first) or "", first[1]):
        return True
    return is_image(run.get(first))


def write_rendered(run: Any, ref: tuple, stem: Path, lossy: bool) -> list[Path]:
    """Write the value of ``ref`` (node, output, item) at ``stem`` (:func:`_rendered`)."""
    return _rendered(
        run.store, run.key_of(ref), ref[1], stem, lambda: write_value(stem, run.get(ref), lossy)
    )
