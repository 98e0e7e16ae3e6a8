"""The cache's locks: an entry's (filelock), exclusive across processes, released on exit; the
cache's in-use lock, which keeps a prune or a clear from taking entries from under a running run."""

from __future__ import annotations

import multiprocessing as mp
import os
from pathlib import Path

import pytest

from stereograph.core.cache import ArtifactStore

KEY = "ab" + "0" * 62


def _try_lock(root: str, queue) -> None:
    with ArtifactStore(root).lock(KEY, blocking=False) as got:
        queue.put(got)


def test_lock_is_exclusive_across_processes_and_released(tmp_path):
    store = ArtifactStore(tmp_path / "cache")
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    with store.lock(KEY) as got:
        assert got
        p = ctx.Process(target=_try_lock, args=(str(tmp_path / "cache"), queue))
        p.start()
        p.join(60)
        assert queue.get(timeout=10) is False  # held here: the other process must not get it
    p = ctx.Process(target=_try_lock, args=(str(tmp_path / "cache"), queue))
    p.start()
    p.join(60)
    assert queue.get(timeout=10) is True  # released on leaving the block


def test_a_second_holder_in_the_same_process_waits(tmp_path):
    store = ArtifactStore(tmp_path / "cache")
    with store.lock(KEY) as first, store.lock(KEY, blocking=False) as second:
        assert first and not second


def test_a_prune_or_clear_waits_for_the_runs_using_the_cache(tmp_path):
    from stereograph.core.cache import ArtifactStore, CacheBusy, in_use

    store = ArtifactStore(tmp_path / "cache")
    store.save("a" * 32, {"x": 1}, {"node": "n"})
    with in_use(store.root):  # a run
        with pytest.raises(CacheBusy):
            store.prune(0, wait_s=0.3)
        with pytest.raises(CacheBusy):
            store.clear(wait_s=0.3)
        assert store.has("a" * 32)
    assert store.prune(0)[0] == 1 and not store.has("a" * 32)  # the run ended: pruned


@pytest.mark.slow
def test_two_runs_and_a_pruning_loop_on_one_cache(tmp_path):
    """(two runs of locate.yaml while `cache prune --max-gb 0` looped: 'internal error: KeyError:
    ('rig', 'views', None)' in 5 of 6 attempts -- an entry pruned under a streamed chunk, recomputed
    from an upstream entry the chunk did not know)"""
    import subprocess
    import sys
    import threading

    from stereograph.core.cache import ArtifactStore, CacheBusy

    root = Path(__file__).resolve().parents[1]
    cache = tmp_path / "cache"
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(root / "pipelines" / "locate.yaml"),
        "--set",
        "rig.n_scenes=8",
        "--set",
        "rig.n_views=6",
        "--cache-dir",
        str(cache),
    ]
    env = {**os.environ, "PYTHONPATH": str(root)}
    subprocess.run(
        cmd + ["--out", str(tmp_path / "warm")], check=True, capture_output=True, env=env
    )
    stop, pruned = threading.Event(), []

    def prune_loop():
        store = ArtifactStore(cache)
        while not stop.is_set():
            try:
                pruned.append(store.prune(0, wait_s=0.2)[0])
            except CacheBusy:
                pass

    t = threading.Thread(target=prune_loop)
    t.start()
    try:
        # (the bug showed in 2 of 3 pairs; the lock itself is the unit test above)
        for k in range(1):
            procs = [
                subprocess.Popen(
                    cmd + ["--out", str(tmp_path / f"r{k}{s}")],
                    stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT,
                    text=True,
                    env=env,
                )
                for s in "ab"
            ]
            for p in procs:
                out = p.communicate(timeout=300)[0]
                assert p.returncode == 0 and "internal error" not in out, out[-2000:]
    finally:
        stop.set()
        t.join()
    assert sum(pruned) > 0  # the loop did prune, between the runs
