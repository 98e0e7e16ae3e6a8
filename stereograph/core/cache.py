"""Content-addressed artifact store (:class:`ArtifactStore`).

An entry's key hashes everything that determines its value (node type, version, code and the
project-local modules it imports (:mod:`~stereograph.core.code_keys`), params, input keys, read
files (:mod:`~stereograph.core.file_index`)). Entries are folders in open formats
(:mod:`~stereograph.core.codecs`), built aside and renamed into place; a corrupt entry is
detected, deleted and recomputed; per-entry locks let two runs share results, and a run's shared
lock (:func:`in_use`) keeps prunes away. Layout: docs/engine.md, docs/cache.md.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import time
import uuid

try:
    import fcntl
except ImportError:  # Windows: no shared locks here (no protection of running runs)
    fcntl = None  # type: ignore[assignment]
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from stereograph.core import hooks
from stereograph.core.codecs import decode, encode, entry_blobs, png_decode
from stereograph.core.digests import digest
from stereograph.core.errors import ConfigError
from stereograph.core.file_index import FileIndex
from stereograph.core.outputs import write_whole

FORMAT = "2"  # bump when the entry layout changes (2: images as PNG, manifest-only entries)


class CorruptEntry(Exception):
    """An entry whose files do not match its manifest."""


class CacheBusy(Exception):
    """A prune or clear that would take entries from under a running run (:func:`in_use`)."""


IN_USE_LOCK = "in-use.lock"


@contextlib.contextmanager
def in_use(root: Path) -> Iterator[None]:
    """Held by a run for as long as it runs (a shared lock on ``<cache>/in-use.lock``): a prune or a
    clear waits for it (:func:`exclusive`), so no entry a run has looked up disappears under it.
    POSIX only (``fcntl``); elsewhere, and on a cache that cannot be written, no protection."""
    fd = _lock_fd(root)
    if fd is None:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_SH)
        yield
    finally:
        os.close(fd)


@contextlib.contextmanager
def exclusive(root: Path, wait_s: float) -> Iterator[None]:
    """The cache to oneself (no run holds :func:`in_use`), waiting at most ``wait_s``;
    :class:`CacheBusy` else."""
    fd = _lock_fd(root)
    if fd is None:
        yield
        return
    try:
        end = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= end:
                    raise CacheBusy(f"a run is using the cache {root}") from None
                time.sleep(0.1)
        yield
    finally:
        os.close(fd)


def _lock_fd(root: Path) -> int | None:
    if fcntl is None:
        return None
    try:
        root.mkdir(parents=True, exist_ok=True)
        return os.open(root / IN_USE_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:  # a read-only cache: nothing can be pruned from it by us either
        return None


class NotStored(Exception):
    """An entry kept as a manifest only: recomputing its value is cheaper than reading it back."""


class ArtifactStore:
    """Entries by key under ``root``; see the module docstring."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.objects = self.root / "objects"
        self.tmp = self.root / "tmp"
        self.locks = self.root / "locks"
        self.notes: list[str] = []  # what a user should know about this cache (read-only, full)
        if self.root.exists() and not self.root.is_dir():
            raise ConfigError(
                f"cache folder {self.root} is an existing file",
                hint="choose another folder with --cache-dir (or STEREOGRAPH_CACHE_DIR, or "
                "the project's "
                "pyproject.toml cache_dir, whichever set this one), or remove that file",
            )
        self.writable = self._probe()
        self.files = FileIndex(self.root)
        self._written = 0

    def _probe(self) -> bool:
        """Whether entries can be stored here, asked without creating anything (``cache info`` and
        ``explain`` leave no trace); a read-only cache is still read."""
        probe = self.root
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not probe.is_dir():
            raise ConfigError(
                f"cache folder {self.root} cannot be made: {probe} is a file",
                hint="choose another folder with --cache-dir (or STEREOGRAPH_CACHE_DIR, or the "
                "project's pyproject.toml cache_dir, whichever set this one)",
            )
        dirs = [probe] + [d for d in (self.objects, self.tmp) if d.is_dir()]
        # access() reports a read-only file system (EROFS) even to root; permissions too for others
        if all(os.access(d, os.W_OK | os.X_OK) for d in dirs):
            return True
        self.notes.append(
            f"cache {self.root} is not writable: results are read from it, new ones are not stored"
        )
        return False

    def _cannot_store(self, e: OSError) -> None:
        if self.writable:
            self.notes.append(
                f"cache {self.root}: cannot store more entries ({e.strerror or e}); the "
                "run goes on "
                "without storing them"
            )
        self.writable = False

    def _dir(self, key: str) -> Path:
        return self.objects / key[:2] / key

    def complete(self, key: str) -> dict[str, Any] | None:
        """The manifest of a complete-looking entry (manifest present, of this :data:`FORMAT`, file
        sizes match), else None; marks the entry used. An entry of another format is computed
        again (and stored anew), never read with this layout's rules."""
        d = self._dir(key)
        try:
            man = json.loads((d / "manifest.json").read_text())
            if man["format"] != FORMAT or not all(
                (d / name).stat().st_size == rec["size"] for name, rec in man["files"].items()
            ):
                return None
            if self.writable:
                with contextlib.suppress(OSError):
                    os.utime(d / "manifest.json")  # last use, for `cache prune`
            return man
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None

    def has(self, key: str) -> bool:
        """A complete-looking entry exists; see :meth:`complete`."""
        return self.complete(key) is not None

    def load(self, key: str) -> dict[str, Any]:
        """The outputs stored under ``key``; :class:`CorruptEntry` if the files fail their
        digests."""
        d = self._dir(key)
        try:
            man = json.loads((d / "manifest.json").read_text())
            blobs = {}
            for name, rec in man["files"].items():
                b = (d / name).read_bytes()
                if digest(b) != rec["digest"]:
                    raise CorruptEntry(f"{name} does not match its digest")
                blobs[name] = b
            if man.get("recompute"):
                raise NotStored(man.get("recompute_reason", "cheaper to recompute than to read"))
            data = json.loads(blobs["data.json"])
            arrays = {}
            if "arrays.npz" in blobs:
                with np.load(io.BytesIO(blobs["arrays.npz"]), allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files}
            for name, b in blobs.items():
                if name.endswith((".png", ".jpg")):
                    arrays[name[:-4]] = png_decode(b)
            return decode(data, arrays)
        except (CorruptEntry, NotStored):
            raise
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise CorruptEntry(str(e)) from e

    def ready_file(self, key: str, output: str) -> Path | None:
        """The stored PNG (JPEG for a lossy output) of a top-level image ``output`` of entry ``key``
        -- the very file a run folder gets for it -- if it matches its digest, else None."""
        d = self._dir(key)
        try:
            man = json.loads((d / "manifest.json").read_text())
            name = man.get("png_outputs", {}).get(output)
            if not isinstance(name, str) or "/" in name:
                return None
            b = (d / name).read_bytes()
            return d / name if digest(b) == man["files"][name]["digest"] else None
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None

    def meta(self, key: str) -> dict[str, Any] | None:
        try:
            return json.loads((self._dir(key) / "manifest.json").read_text())
        except (OSError, ValueError):
            return None

    def save(
        self,
        key: str,
        outputs: dict[str, Any],
        meta: dict[str, Any] | None = None,
        compute_seconds: float | None = None,
        encoded: dict[str, bytes] | None = None,
    ) -> None:
        """Store ``outputs`` atomically (temp folder + rename); a racing writer's copy is kept.

        On a read-only or full cache nothing is stored (the run goes on; :attr:`notes` says so).
        A value that is not plain data raises ``TypeError`` whatever the cache.

        ``compute_seconds``: what computing ``outputs`` took, given when the caller may do without a
        stored copy. If it is less than encoding the entry's images took (measured here, now:
        decoding costs about as much), only the manifest is kept (see :class:`NotStored`): the entry
        reads as fresh, and whoever needs its value computes it again from its cached inputs.

        ``encoded``: top-level image outputs already encoded as JPEG (:func:`jpeg_roundtrip`; the
        value in ``outputs`` is what those bytes decode to), stored as those bytes.
        """
        arrays: dict[str, np.ndarray] = {}
        tree = encode(outputs, arrays, "outputs")
        if not self.writable:
            return
        blobs, ready, codec_seconds = entry_blobs(tree, arrays, encoded or {})
        manifest = {
            "key": key,
            "format": FORMAT,
            "created": time.time(),
            "meta": meta or {},
            "files": {n: {"size": len(b), "digest": digest(b)} for n, b in blobs.items()},
            **({"png_outputs": ready} if ready else {}),
        }
        images = any(n.endswith((".png", ".jpg")) for n in blobs)
        if compute_seconds is not None and images and compute_seconds < codec_seconds:
            # only the manifest: the entry reads as fresh, and its value is computed again from its
            # (cached) inputs by whoever needs it -- cheaper than reading it back
            blobs, manifest["files"], manifest["recompute"] = {}, {}, True
            manifest["recompute_reason"] = (
                f"computing took {compute_seconds * 1e3:.1f} ms, encoding its images "
                f"{codec_seconds * 1e3:.1f} ms"
            )
            manifest.pop("png_outputs", None)
        self._write_entry(key, blobs, manifest)

    def _write_entry(self, key: str, blobs: dict[str, bytes], manifest: dict[str, Any]) -> None:
        tmp = self.tmp / uuid.uuid4().hex
        try:
            tmp.mkdir(parents=True)
        except OSError as e:
            self._cannot_store(e)
            return
        try:
            for name, b in blobs.items():
                (tmp / name).write_bytes(b)
            # last: marks the entry complete
            (tmp / "manifest.json").write_text(json.dumps(manifest))
            final = self._dir(key)
            final.parent.mkdir(parents=True, exist_ok=True)
            if final.exists():
                shutil.rmtree(final, ignore_errors=True)  # a stale/corrupt entry
            try:
                os.rename(tmp, final)
                self._written += sum(len(b) for b in blobs.values())
            except OSError:
                pass  # another run put it there first: its copy is as good as ours
        except OSError as e:  # a full disk, say: keep going without this entry
            self._cannot_store(e)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)

    def delete(self, key: str) -> None:
        d = self._dir(key)
        if d.exists() and self.writable:
            trash = self.tmp / f"del-{uuid.uuid4().hex}"
            trash.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(OSError):
                os.rename(d, trash)
            shutil.rmtree(trash, ignore_errors=True)

    @contextlib.contextmanager
    def lock(self, key: str, blocking: bool = True) -> Iterator[bool]:
        """An exclusive per-entry lock across processes; yields whether it was acquired.

        ``filelock`` rather than ``fcntl``: the same lock on Windows (``msvcrt``) as on POSIX.
        """
        # (here: a replayed rerun reads entries and takes no lock)
        from filelock import FileLock, Timeout

        path = self.locks / key[:2] / f"{key}.lock"
        try:
            if not self.writable:
                raise PermissionError("read-only cache")
            path.parent.mkdir(parents=True, exist_ok=True)
            # thread_local=False: the executor may release from another thread than it acquired in
            lock = FileLock(path, mode=0o644, thread_local=False)
            lock.acquire(blocking=blocking)
            got = True
        except Timeout:  # held by another run (non-blocking only)
            got = False
        # nothing will be stored, so there is nothing to share: compute without a lock
        except OSError:
            yield True
            return
        try:
            yield got
        finally:
            if got:
                with contextlib.suppress(OSError):
                    lock.release()

    # ---- bookkeeping for `explain`

    def record(self, pipeline_id: str, node: str, components: dict[str, Any]) -> None:
        if not self.writable:
            return
        try:
            write_whole(
                self.root / "last" / pipeline_id / f"{node}.json", json.dumps(components).encode()
            )
        except OSError as e:
            self._cannot_store(e)

    def last(self, pipeline_id: str, node: str) -> dict[str, Any] | None:
        try:
            return json.loads((self.root / "last" / pipeline_id / f"{node}.json").read_text())
        except (OSError, ValueError):
            return None

    # ---- `stereograph cache info|clear`

    def info(self, budget: int | None = None) -> dict[str, Any]:
        """Entries, bytes (entries and their rendered files) by node type, and the budget if
        given."""
        n, size, by_node = 0, 0, {}
        for _used, s, key, d in self._usage():
            if d is None:  # rendered files whose entry is gone
                size += s
                continue
            t = ((self.meta(key) or {}).get("meta", {}) or {}).get("type", "?")
            n += 1
            size += s
            cnt, sz = by_node.get(t, (0, 0))
            by_node[t] = (cnt + 1, sz + s)
        left = self.abandoned()
        return {
            "root": str(self.root),
            "entries": n,
            "bytes": size,
            "by_type": by_node,
            "budget": budget,
            "abandoned": len(left),
            "abandoned_bytes": sum(b for _d, b in left),
        }

    def _usage(self) -> list[tuple[float, int, str, Path | None]]:
        """(last use, bytes, key, entry folder or None) per entry, its rendered files counted with
        it."""

        def du(d: Path) -> int:
            with contextlib.suppress(OSError):
                return sum(f.stat().st_size for f in d.iterdir() if f.is_file())
            return 0

        rendered: dict[str, list[Path]] = {}
        rroot = self.root / "rendered"
        if rroot.is_dir():
            for sub in rroot.iterdir():
                if sub.is_dir() and not sub.is_symlink():
                    for r in sub.iterdir():
                        # (nothing else is pruned)
                        if _named(r, "rendered", 1) and r.name[:2] == sub.name:
                            rendered.setdefault(r.name.split("-", 1)[0], []).append(r)
        rows = []
        if self.objects.is_dir():
            for d in self._entries():
                try:
                    used = (d / "manifest.json").stat().st_mtime
                except OSError:
                    used = 0.0
                size = du(d) + sum(du(r) for r in rendered.pop(d.name, []))
                rows.append((used, size, d.name, d))
        for key, dirs in rendered.items():
            rows.append((0.0, sum(du(r) for r in dirs), key, None))
        return rows

    def abandoned(self) -> list[tuple[Path, int]]:
        """(folder, bytes) of each ``tmp/`` folder a killed run left behind (SIGKILL, power cut, out
        of memory): one untouched for :data:`ABANDONED_AFTER_S`. An entry is written in seconds, so
        such a folder has no writer; nothing else would ever remove it."""
        if not self.tmp.is_dir() or self.tmp.is_symlink():
            return []
        now, out = time.time(), []
        with contextlib.suppress(OSError):
            for d in self.tmp.iterdir():
                if d.is_symlink() or not d.is_dir() or not _named(d, "tmp", 0):
                    continue
                try:
                    stats = [d.stat(), *(f.stat() for f in d.rglob("*"))]
                except OSError:  # (being removed now)
                    continue
                if now - max(st.st_mtime for st in stats) > ABANDONED_AFTER_S:
                    out.append((d, sum(st.st_size for st in stats[1:])))
        return out

    def sweep_abandoned(self) -> int:
        """Remove what killed runs left in ``tmp/`` (:meth:`abandoned`); returns the bytes freed."""
        freed = 0
        for d, size in self.abandoned():
            shutil.rmtree(d, ignore_errors=True)
            freed += size
        return freed

    def prune(self, max_bytes: int, wait_s: float = 0.0) -> tuple[int, int]:
        """Delete the least recently used entries until the store holds at most ``max_bytes``.

        Returns (entries removed, bytes freed). Rendered output files go with their entry. It waits
        up to ``wait_s`` for running runs to end (:func:`in_use`), then raises :class:`CacheBusy`:
        an entry is never taken from under a run. What killed runs left in ``tmp/``
        (:meth:`abandoned`) goes first, whatever the budget.
        """
        if not self.writable:
            raise ConfigError(
                f"cannot prune cache {self.root}: it is not writable", hint="check its permissions"
            )
        with exclusive(self.root, wait_s):
            return self._prune(max_bytes)

    def _prune(self, max_bytes: int) -> tuple[int, int]:
        removed, freed = 0, self.sweep_abandoned()
        rows = self._usage()
        total = sum(r[1] for r in rows) + freed
        for _used, size, key, d in sorted(rows, key=lambda r: r[0]):
            if total - freed <= max_bytes:
                break
            if d is not None:
                self.delete(key)
                removed += 1
            for r in (self.root / "rendered" / key[:2]).glob(f"{key}-*"):
                shutil.rmtree(r, ignore_errors=True)
            freed += size
        # rerun memos hard-link run-folder files: they must not keep pruned images on disk
        if removed:
            hooks.announce("cache_pruned", self.root)
        return removed, freed

    def stored_bytes(self) -> int:
        """Bytes this store object wrote in this process (decides whether a prune is worth a
        look)."""
        return self._written

    def took_in(self, notes: list[str], stored_bytes: int) -> None:
        """Count what another process wrote into this cache for this run, and what it noted."""
        self.notes += [m for m in notes if m not in self.notes]
        self._written += stored_bytes

    def _entries(self) -> Iterator[Path]:
        """Entry folders (a stray file such as .DS_Store, or a half-deleted entry, is skipped)."""
        for sub in self.objects.iterdir():
            if sub.is_dir() and not sub.is_symlink():
                for d in sub.iterdir():
                    if (
                        d.is_dir()
                        and not d.is_symlink()
                        and d.name[:2] == sub.name
                        and _named(d, "objects", 1)
                    ):
                        yield d

    def clear(self, wait_s: float = 0.0) -> int:
        """Remove every entry and what a cache keeps beside them; returns the number of entries.
        Waits up to ``wait_s`` for running runs to end (:class:`CacheBusy` then), as :meth:`prune`.

        Only what a cache holds, named as the store names it, is removed (see
        :data:`_CACHE_LAYOUT`): a cache folder that is a folder of yours -- ``--cache-dir ~`` by
        mistake, a project's ``pyproject.toml`` or a symbolic link that points it there -- loses
        nothing else (its ``tmp/``, its ``files.json``). A folder left empty is removed; one holding
        anything else stays."""
        with exclusive(self.root, wait_s):
            return self._clear()

    def _clear(self) -> int:
        n = len(list(self._entries())) if self.objects.is_dir() else 0
        for sub, levels in _CACHE_LAYOUT.items():
            _sweep(self.root / sub, levels)
        index = self.root / "files.json"
        with contextlib.suppress(OSError, ValueError):
            data = (
                json.loads(index.read_text())
                if index.is_file() and not index.is_symlink()
                else None
            )
            # (a FileIndex)
            if isinstance(data, dict) and all(isinstance(v, list) for v in data.values()):
                index.unlink()
        lock = self.root / IN_USE_LOCK
        with contextlib.suppress(OSError):
            if lock.is_file() and not lock.is_symlink() and lock.stat().st_size == 0:
                lock.unlink()  # (held by us: a run that starts now makes it again)
        return n


_HEX = r"[0-9a-f]"
# a tmp/ folder untouched this long was left by a killed run (see abandoned())
ABANDONED_AFTER_S = 3600.0
# What ArtifactStore.clear removes: under each folder of the cache, the names at each level down
# to what is removed whole (an entry's folder, a lock file); anything else is left where it is.
_CACHE_LAYOUT: dict[str, list[str]] = {
    "objects": [f"{_HEX}{{2}}", f"c?{_HEX}{{32}}"],  # objects/ab/<key>/ (c...: a content key)
    "rendered": [f"{_HEX}{{2}}", rf"c?{_HEX}{{32}}-[\w.-]+"],  # rendered/ab/<key>-<output>/
    "locks": [f"{_HEX}{{2}}", rf"c?{_HEX}{{32}}\.lock"],  # locks/ab/<key>.lock
    "last": [f"{_HEX}{{32}}", r"[\w.-]+\.json"],  # last/<pipeline id>/<node>.json
    "reruns": [f"{_HEX}{{24}}"],  # reruns/<memo id>/
    # tmp/<uuid>/ (an entry, a memo being made)
    "tmp": [rf"(?:(?:del|memo|r)-)?{_HEX}{{32}}"],
}


def _named(p: Path, folder: str, level: int) -> bool:
    """Whether ``p``'s name is one the store gives at that level of ``folder``
    (:data:`_CACHE_LAYOUT`)."""
    return re.fullmatch(_CACHE_LAYOUT[folder][level], p.name) is not None


def _sweep(folder: Path, levels: list[str]) -> None:
    """Remove what matches ``levels`` under ``folder`` (never through a symbolic link), then the
    folders that are left empty, ``folder`` included."""
    if folder.is_symlink() or not folder.is_dir():
        return
    with contextlib.suppress(OSError):
        for p in folder.iterdir():
            if p.is_symlink() or not re.fullmatch(levels[0], p.name):
                continue
            if len(levels) > 1:
                _sweep(p, levels[1:])
            elif p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        folder.rmdir()  # (only when empty)
