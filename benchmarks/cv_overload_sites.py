"""Where OpenCV's Python binding tries a call's next overload: the window in which a stop signal
crashes the process (``nodes/contracts/cv_overloads.py``), found under gdb.

Usage::

    python benchmarks/cv_overload_sites.py -- python -m pytest -n 0 tests/test_segment_methods.py
    python benchmarks/cv_overload_sites.py -- stereograph run pipelines/pick.yaml

Needs gdb. First, for the installed cv2 build, it finds where the binding calls ``PyObject_Str``
on a conversion error, by running a known fallback (``cv2.Canny`` on two derivative images) under
gdb. Then it runs the command under gdb with a breakpoint there that records the Python stack at
each hit, and prints each site (its innermost frame in this project) with its count. A site
marked ``held`` ran within ``stop_signals_held``: it is safe. Exit status 1 when a site in
``nodes/`` or ``stereograph/`` is not held. Only the command's own process is traced: run pytest
with ``-n 0`` and a pipeline without ``--workers``. The whole suite takes about 25 minutes.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Both gdb scripts: where the cv2 library is loaded (its lowest mapping), in gdb's Python.
BASE = """
import gdb
def _base():
    lo = None
    for line in gdb.execute("info proc mappings", to_string=True).splitlines():
        if {so!r} in line:
            a = int(line.split()[0], 16)
            lo = a if lo is None else min(lo, a)
    return lo
"""

FIND = (
    BASE
    + """
class _Caller(gdb.Breakpoint):
    def stop(self):
        base = _base()
        pc = gdb.newest_frame().older().pc()
        if base is not None and base <= pc < base + 0x10000000:
            print("CV2-OFFSET", hex(pc - base))
        return False
gdb.execute("set pagination off")
_Caller("PyObject_Str")
"""
)

TRIGGER = (
    "import cv2, numpy as np; d = np.zeros((8, 8), np.int16); "
    "cv2.Canny(d, d, 30.0, 90.0)"  # not the first overload: Canny(image, t1, t2)
)

# Run inside the traced process at each hit: the Python stack, and whether a stop signal would be
# held (stop_signals_held swaps in a handler of nodes.contracts.cv_overloads).
RECORD = (
    "import json as _j, signal as _s, traceback as _t;"
    "_h = getattr(_s.getsignal(_s.SIGTERM), '__module__', '') == 'nodes.contracts.cv_overloads';"
    "_f = open({out!r}, 'a');"
    "_f.write(_j.dumps([_h, [(f.filename, f.lineno, f.name) for f in _t.extract_stack()]])"
    " + chr(10)); _f.close()"
)

SWEEP = (
    BASE
    + """
state = {{"set": False}}
def _loaded(_event):
    base = None if state["set"] else _base()
    if base is not None:
        state["set"] = True
        bp = gdb.Breakpoint("*0x%x" % (base + {offset}))
        bp.commands = "silent\\ncall (int)PyRun_SimpleString(%s)\\ncontinue" % {code!r}
gdb.events.new_objfile.connect(_loaded)
gdb.execute("set pagination off")
gdb.execute("set print thread-events off")
for s in ("SIGINT", "SIGTERM", "SIGCHLD", "SIGPIPE", "SIGALRM", "SIGUSR1", "SIGUSR2", "SIGHUP"):
    gdb.execute("handle %s nostop noprint pass" % s)
"""
)


def _gdb(script: str, argv: list[str], log: Path) -> int:
    """Run ``argv`` under gdb with the Python ``script``; its output to ``log``. A script (such as
    the ``stereograph`` command) runs through this Python, since gdb traces executables only."""
    exe = shutil.which(argv[0]) or argv[0]
    with contextlib.suppress(OSError), open(exe, "rb") as f:
        if f.read(2) == b"#!":
            argv = [sys.executable, exe, *argv[1:]]
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(script)
    cmd = ["gdb", "-q", "-batch", "-x", f.name, "-ex", "run", "--args", *argv]
    with log.open("w") as out:
        return subprocess.call(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)


def cv2_library() -> str:
    """The file name of the installed cv2 extension module."""
    import cv2

    found = sorted(Path(cv2.__file__).parent.glob("cv2*.so"))
    if not found:
        sys.exit("cv_overload_sites: no cv2*.so next to cv2/__init__.py (a Linux build is needed)")
    return found[0].name


def find_offset(so: str, work: Path) -> int:
    """The return address of the binding's ``PyObject_Str`` call, from the library's base."""
    log = work / "find.log"
    _gdb(FIND.format(so=so), [sys.executable, "-c", TRIGGER], log)
    offsets = {line.split()[1] for line in log.read_text().splitlines() if "CV2-OFFSET" in line}
    if len(offsets) != 1:
        sys.exit(f"cv_overload_sites: expected one call site in {so}, found {sorted(offsets)}")
    return int(offsets.pop(), 16)


def project_site(stack: list) -> tuple[str, int, str] | None:
    """The innermost frame of ``stack`` in this project (a path relative to it), if any."""
    for filename, line, name in reversed(stack):
        if filename.startswith("<"):  # the recording code itself, or code compiled from text
            continue
        try:
            rel = Path(filename).resolve().relative_to(ROOT)
        except ValueError:
            continue
        if rel.parts[0] != "benchmarks":
            return str(rel), line, name
    return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("command", nargs=argparse.REMAINDER, help="the command to trace, after --")
    a = ap.parse_args(argv)
    command = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not command:
        ap.error("give the command to trace after --")
    so = cv2_library()
    with tempfile.TemporaryDirectory() as td:
        work = Path(td)
        offset = find_offset(so, work)
        hits = work / "hits.jsonl"
        code = json.dumps(RECORD.format(out=str(hits)))  # a C string literal for gdb's `call`
        rc = _gdb(SWEEP.format(so=so, offset=offset, code=code), command, work / "sweep.log")
        if rc != 0:  # (a failing test or run still shows its sites; its output says why it failed)
            print("".join((work / "sweep.log").read_text().splitlines(True)[-15:]))
        records = [json.loads(x) for x in hits.read_text().splitlines()] if hits.exists() else []
    sites = collections.Counter((project_site(stack), held) for held, stack in records)
    print(f"{so}: fallback call at +{offset:#x}; the command exited {rc}; {len(records)} hits")
    unheld = 0
    for (site, held), n in sites.most_common():
        where = f"{site[0]}:{site[1]} ({site[2]})" if site else "(outside the project)"
        print(f"  {n:6d}  {where}{'  held' if held else ''}")
        if not held and site and site[0].split("/")[0] in ("nodes", "stereograph"):
            unheld += 1
    print(f"{unheld} site(s) in nodes/ or stereograph/ not held")
    return 1 if unheld else 0


if __name__ == "__main__":
    sys.exit(main())
