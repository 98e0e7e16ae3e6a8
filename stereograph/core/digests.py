"""Content digests (blake2b, 128 bits) of bytes, files and JSON-able values.

A module of its own, importing only the standard library, so that the rerun fast path
(:mod:`stereograph.app.rerun`) checks a run folder's files without importing NumPy.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

# A file digest taken within this of the file's modification time may miss an edit made in the
# same timestamp tick ("racy" files, as git calls them): coarser than any file system's (FAT: 2 s).
RACY_NS = 2_000_000_000


def digest(data: bytes) -> str:
    return hashlib.blake2b(data, digest_size=16).hexdigest()


def hash_json(obj: Any) -> str:
    """Digest of a JSON-able object in canonical form (sorted keys, no spaces)."""
    return digest(json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True).encode())


def file_digest(path: Path) -> str:
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
