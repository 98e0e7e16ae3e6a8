"""The cache's per-entry lock (filelock): exclusive across processes, released on exit."""

from __future__ import annotations

import multiprocessing as mp

from stereograph.cache import ArtifactStore

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
