"""One thread per library thread pool, for processes that share the cores with a worker pool.

With ``--workers N`` the pool's processes are the parallelism: a library's own threads on top of
them only cost CPU. OpenBLAS (under NumPy) is the costly one: its threads spin while they wait for
work, and it reads ``OPENBLAS_NUM_THREADS`` once, when NumPy is imported -- so a command's own
process must set the variables before anything imports NumPy (measured on a 2-core machine: the
``stereograph`` process of a ``locate.yaml --workers 2`` run spent 7.4 s of CPU with OpenBLAS's
default threads, 4.8 s with one). OpenCV reads its variable when it first starts its threads.
"""

from __future__ import annotations

import os

__all__ = ["ONE_THREAD", "one_thread_each", "pool_requested"]

ONE_THREAD = {
    "OPENCV_FOR_THREADS_NUM": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


def one_thread_each() -> None:
    """One thread per library pool in this process (and those it starts), unless the user set the
    variable: for a worker process, and for a ``--workers`` command's own process."""
    for k, v in ONE_THREAD.items():
        os.environ.setdefault(k, v)


def pool_requested(argv: list[str]) -> bool:
    """Whether a command line asks for a local worker pool (``--workers N``, N > 1, no ``--dask``).

    Read from the raw arguments, before they are parsed: parsing some commands imports NumPy.
    A malformed value counts as no pool (the parser then says what is wrong).
    """
    if any(a == "--dask" or a.startswith("--dask=") for a in argv):
        return False
    for k, a in enumerate(argv):
        value = (
            a.split("=", 1)[1]
            if a.startswith("--workers=")
            else (argv[k + 1] if a == "--workers" and k + 1 < len(argv) else None)
        )
        if value is not None:
            try:
                return int(value) > 1
            except ValueError:
                return False
    return False
