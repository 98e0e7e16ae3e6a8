"""A fast path in front of file digests: a file's digest (and, for a code file, its import
statements) reused while its size, times and inode are unchanged (:class:`FileIndex`).

Public: :class:`FileIndex`.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import time
from pathlib import Path

from stereograph.core.code_keys import import_statements
from stereograph.core.digests import RACY_NS, file_digest
from stereograph.core.outputs import write_whole


class FileIndex:
    """A fast path in front of content digests of input files.

    A file's digest is reused only when its size, mtime, ctime and inode all match the ones
    recorded with the digest, and its mtime was at least ``digests.RACY_NS`` older than the moment
    the digest was taken. The ctime cannot be set by a user tool, so a file edited and
    then given its old mtime back (``touch -r``, a restore) is hashed again; the age rule covers
    an edit in the same timestamp tick as the recording ("racy" files, as git calls them) on a
    file system with coarse timestamps. Otherwise the content is hashed.
    """

    def __init__(self, root: Path | None):
        self.path = root / "files.json" if root else None
        self.data: dict[str, list] = {}
        self.dirty = False
        if self.path and (self.path.exists() or self.path.is_symlink()):
            try:
                data = json.loads(self.path.read_text()) if not self.path.is_symlink() else None
            except (OSError, ValueError):
                data = None
            if isinstance(data, dict) and all(isinstance(v, list) for v in data.values()):
                self.data = data
            # someone's own files.json (a --cache-dir that is a folder of theirs): never overwritten
            else:
                self.path = None

    def digest(self, path: Path) -> str:
        p = str(Path(path).resolve())
        try:
            st = os.stat(p)
        except OSError:
            return "missing"
        # a device or FIFO would never end (/dev/zero) or never answer
        if not stat.S_ISREG(st.st_mode):
            return "not a regular file"
        stamp = [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]
        got = self._record(p)
        if got is not None and got[0] == stamp and got[2] - stamp[1] >= RACY_NS:
            return got[1]
        try:
            d = file_digest(Path(p))
        except OSError:
            return "unreadable"
        self.data[p] = [*stamp, d, time.time_ns()]
        self.dirty = True
        return d

    def recorded(self, path: str) -> tuple[list[int], str, int] | None:
        """``(stamp, digest, recorded_ns)`` of a file's record, None when there is none; the stamp
        is ``[size, mtime_ns, ctime_ns, inode]`` as the file had when its digest was taken."""
        return self._record(str(Path(path).resolve()))

    def _record(self, resolved: str) -> tuple[list[int], str, int] | None:
        rec = self.data.get(resolved)
        if isinstance(rec, list) and len(rec) in (6, 7):  # (7: with its import statements)
            return rec[:4], rec[4], rec[5]
        return None

    def statements(self, path: str) -> tuple:
        """A source file's :func:`import_statements`, kept beside its digest: parsed again only
        when the file changed (the digest's record is renewed then)."""
        p = str(Path(path).resolve())
        self.digest(Path(p))
        rec = self.data.get(p)
        if isinstance(rec, list) and len(rec) == 7:
            with contextlib.suppress(TypeError, ValueError):
                return tuple((str(m), int(lv), tuple(map(str, ns))) for m, lv, ns in rec[6])
        got = import_statements(p)
        if isinstance(rec, list) and len(rec) >= 6:
            self.data[p] = [*rec[:6], [[m, lv, list(ns)] for m, lv, ns in got]]
            self.dirty = True
        return got

    def save(self) -> None:
        if self.path and self.dirty:
            # a read-only or full cache: the digests are only a fast path
            with contextlib.suppress(OSError):
                write_whole(self.path, json.dumps(self.data).encode())
            self.dirty = False
