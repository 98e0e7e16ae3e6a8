"""Content-addressed artifact store.

An entry's key hashes everything that determines its value (node type, version, code and the
project-local modules it imports, params, input keys, read files). Entries are folders in open
formats, built aside and renamed into place; a corrupt entry is detected, deleted and
recomputed; per-entry locks let two runs share results. Layout: docs/engine.md, docs/cache.md.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import importlib.util
import json
import os
import shutil
import stat
import sys
import sysconfig
import time
import uuid

try:
    import fcntl
except ImportError:  # Windows: no shared locks here (no protection of running runs)
    fcntl = None  # type: ignore[assignment]
from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from stereograph.core import hooks
from stereograph.core.digests import digest, file_digest, hash_json
from stereograph.core.errors import ConfigError

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
    import weakref

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
    decoded = _png_decode(data)
    key = id(decoded)
    _DECODED_FROM[key] = (weakref.ref(decoded, lambda _r, k=key: _DECODED_FROM.pop(k, None)), data)
    return data, decoded


def _png_decode(data: bytes) -> np.ndarray:
    import cv2

    a = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if a is None or a.dtype != np.uint8:
        raise ValueError("an image file of the entry does not decode")
    return a


# --------------------------------------------------------------------------- plain data <-> files


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


# --------------------------------------------------------------------------- source-code hashing

_SYSTEM_DIRS = tuple(
    str(Path(p).resolve())
    for p in {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
)
_ENGINE_DIR = str(Path(__file__).resolve().parent)


def _is_local(path: str) -> bool:
    """Project-local source (not stdlib, not site-packages, not the engine itself)."""
    p = str(Path(path).resolve())
    return p.endswith(".py") and not p.startswith(_SYSTEM_DIRS) and not p.startswith(_ENGINE_DIR)


@lru_cache(maxsize=1024)
def _top_is_local(top: str) -> bool:
    """Whether a top-level package could hold project-local modules. Asking about ``pkg.sub``
    imports ``pkg``: for a site-packages or stdlib package (matplotlib, say) that costs a second
    and cannot find anything local, so such names are not looked up at all."""
    try:
        spec = importlib.util.find_spec(top)  # a top-level name imports nothing
    except (ImportError, ValueError, AttributeError):
        return False
    if spec is None:
        return False
    if spec.origin and spec.origin not in ("namespace", "built-in", "frozen"):
        return _is_local(spec.origin)
    return any(
        _is_local(str(Path(p) / "__init__.py")) for p in (spec.submodule_search_locations or [])
    )


def _find_origin(name: str) -> str | None:
    if "." in name and not _top_is_local(name.partition(".")[0]):
        return None
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError, AttributeError):
        return None
    return spec.origin if spec and spec.origin and spec.origin.endswith(".py") else None


def import_statements(path: str) -> tuple:
    """The import statements of a source file, ``(module, level, names)`` each (``import a.b``:
    ``("a.b", 0, ())``); what a file imports depends on its bytes only (:class:`FileIndex` keeps
    it, so that a run parses only the files changed since)."""
    try:
        tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    except (OSError, SyntaxError):
        return ()
    out: list[tuple] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, 0, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.module or "", node.level, tuple(a.name for a in node.names)))
    return tuple(out)


@lru_cache(maxsize=512)
def _statements_at(path: str, mtime_ns: int) -> tuple:
    return import_statements(path)  # (without a store: once per file and process)


@lru_cache(maxsize=512)
def _imports_of(statements: tuple, package: str) -> tuple[str, ...]:
    """Local modules a file's import statements import (resolved to file paths)."""
    names: list[str] = []
    for module, level, members in statements:
        if not members:  # import a.b
            names.append(module)
            continue
        base = module
        if level:
            parts = package.split(".") if package else []
            parts = parts[: len(parts) - (level - 1)] if level > 1 else parts
            base = ".".join(parts + ([module] if module else []))
        names.append(base)
        names += [f"{base}.{a}" for a in members if base]
    found = []
    for n in names:
        if not n:
            continue
        origin = _find_origin(n)
        if origin and _is_local(origin):
            found.append(str(Path(origin).resolve()))
    return tuple(sorted(set(found)))


@lru_cache(maxsize=8192)
def _resolved(file: str) -> str:
    return str(Path(file).resolve())


# resolved module file -> module name, for the sys.modules it was built from
_NAMES: dict[str, str] = {}
_NAMES_SEEN = [0]


def _module_name_for(path: str) -> str:
    # resolving every loaded module's path on every call was most of a cached rerun's time
    if len(sys.modules) != _NAMES_SEEN[0] or path not in _NAMES:
        _NAMES.clear()
        for name, mod in list(sys.modules.items()):
            f = getattr(mod, "__file__", None)
            if isinstance(f, str):
                _NAMES.setdefault(_resolved(f), name)
        _NAMES_SEEN[0] = len(sys.modules)
    return _NAMES.get(path, "")


def code_files(module_file: str, index: FileIndex | None = None) -> list[str]:
    """A node module and every project-local module it imports, transitively (each file's import
    statements from ``index`` where it has them)."""
    seen: set[str] = set()
    todo = [str(Path(module_file).resolve())]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        modname = _module_name_for(path)
        package = modname if path.endswith("__init__.py") else modname.rpartition(".")[0]
        try:
            mtime = os.stat(path).st_mtime_ns
        except OSError:
            continue
        statements = index.statements(path) if index else _statements_at(path, mtime)
        todo += [p for p in _imports_of(statements, package) if p not in seen]
    return sorted(seen)


def code_hash(fn: Any, index: FileIndex | None = None) -> tuple[str, dict[str, str]]:
    """Digest of a node function's source and its local imports, and the per-file digests
    (through a store's ``index`` when given: files unchanged since are neither read nor parsed)."""
    mod = sys.modules.get(fn.__module__)
    module_file = getattr(mod, "__file__", None)
    if not module_file:
        return digest(fn.__qualname__.encode()), {}
    files = {}
    for f in code_files(module_file, index):
        if index is not None:
            files[f] = index.digest(Path(f))
            continue
        try:
            files[f] = digest(Path(f).read_bytes())
        except OSError:
            files[f] = "missing"
    return hash_json(files), files


# --------------------------------------------------------------------------- files a node reads


RACY_SECONDS = 2.0  # coarser than any file system's timestamps (FAT: 2 s)


class FileIndex:
    """A fast path in front of content digests of input files.

    A file's digest is reused only when its size, mtime, ctime and inode all match the ones
    recorded with the digest, and its mtime was at least :data:`RACY_SECONDS` older than the
    moment the digest was taken. The ctime cannot be set by a user tool, so a file edited and
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
        rec = self.data.get(p)
        if (
            isinstance(rec, list)
            and len(rec) in (6, 7)  # (7: with its import statements)
            and rec[:4] == stamp
            and rec[5] - rec[1] >= RACY_SECONDS * 1e9
        ):
            return rec[4]
        try:
            d = file_digest(Path(p))
        except OSError:
            return "unreadable"
        self.data[p] = [*stamp, d, time.time_ns()]
        self.dirty = True
        return d

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
                _atomic_write(self.path, json.dumps(self.data).encode())
            self.dirty = False


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


# --------------------------------------------------------------------------- the store


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
        """The manifest of a complete-looking entry (manifest present, file sizes match), else None;
        marks the entry used."""
        d = self._dir(key)
        try:
            man = json.loads((d / "manifest.json").read_text())
            if not all(
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
                import io

                with np.load(io.BytesIO(blobs["arrays.npz"]), allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files}
            for name, b in blobs.items():
                if name.endswith((".png", ".jpg")):
                    arrays[name[:-4]] = _png_decode(b)
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
        blobs, ready, codec_seconds = _entry_blobs(tree, arrays, encoded or {})
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
            _atomic_write(
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
    import re

    return re.fullmatch(_CACHE_LAYOUT[folder][level], p.name) is not None


def _sweep(folder: Path, levels: list[str]) -> None:
    """Remove what matches ``levels`` under ``folder`` (never through a symbolic link), then the
    folders that are left empty, ``folder`` included."""
    import re

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


def _entry_blobs(
    tree: Any, arrays: dict[str, np.ndarray], encoded: dict[str, bytes]
) -> tuple[dict[str, bytes], dict[str, str], float]:
    """``(blobs, png_outputs, codec_seconds)``: an entry's files -- data.json, 8-bit images as PNG
    (lossless, 3-10x smaller than raw) or the JPEG bytes given, the other arrays in one npz -- and
    which top-level output each image file is (the run folder copies it as it is)."""
    import io

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
