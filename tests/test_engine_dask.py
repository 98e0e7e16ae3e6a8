"""The Dask executor on a real LocalCluster (2 worker processes): same results as serial, a node
failing on a worker, a worker killed mid-task. One cluster for the module keeps this ~30 s."""

from __future__ import annotations

import pytest

pytest.importorskip("distributed")

import dask  # noqa: E402

from stereograph.core.executors import DaskExecutor  # noqa: E402
from stereograph.core.runner import run_pipeline  # noqa: E402
from tests.test_engine_items import write_pipeline  # noqa: E402


@pytest.fixture(scope="module")
def dask_local():
    # a task is declared lost after its second worker death (default 3: slower tests, same logic)
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        ex = DaskExecutor(workers=2)
    yield ex
    ex.close()


def run(p, tmp_path, sub, **kw):
    return run_pipeline(p, [], out_dir=tmp_path / sub, **kw)


@pytest.mark.slow
def test_dask_gives_the_serial_result_and_shares_the_cache(tmp_path, dask_local):
    p = write_pipeline(tmp_path, "{n: 8, size: 16}")
    serial = run(p, tmp_path, "o1", use_cache=False)
    r = run(p, tmp_path, "o2", cache_dir=tmp_path / "cache", executor=dask_local)
    assert r.ok and r.reports["src"].items_ran == 8 and r.reports["power"].items_ran == 8
    assert r.outputs("total", "total") == serial.outputs("total", "total")  # bit for bit
    assert r.outputs("report", "report") == serial.outputs("report", "report")
    again = run(p, tmp_path, "o3", cache_dir=tmp_path / "cache", executor=dask_local)
    assert set(again.status.values()) == {"cached"}


def test_a_node_failing_on_a_worker_fails_that_item_as_in_serial(tmp_path, dask_local):
    p = write_pipeline(tmp_path, "{n: 5, fail: [m003]}")
    serial = run(p, tmp_path, "o1", use_cache=False)
    r = run(p, tmp_path, "o2", use_cache=False, executor=dask_local)
    assert r.status == serial.status and r.status["src"] == "partial"
    assert (
        r.reports["src"].error == serial.reports["src"].error
        and "m003 is broken" in r.reports["src"].error
    )
    assert set(r.item_errors) == {("src", "m003")}
    assert r.outputs("total", "total") == serial.outputs("total", "total")


def test_a_worker_killed_mid_task_is_replaced_and_the_run_completes(tmp_path, dask_local):
    marker = tmp_path / "killed-once"
    p = write_pipeline(tmp_path, f"{{n: 6, kill_once: '{marker}'}}")
    marker.write_text("not this time")  # (the serial run would kill the test process)
    serial = run(p, tmp_path, "o1", use_cache=False)
    marker.unlink()
    r = run(p, tmp_path, "o2", cache_dir=tmp_path / "cache", executor=dask_local)
    assert marker.exists()  # a worker did die running m001
    assert r.ok and r.reports["src"].items_ran == 6
    assert r.outputs("total", "total") == serial.outputs("total", "total")


@pytest.mark.slow
def test_a_task_that_keeps_killing_workers_is_lost_alone(tmp_path, dask_local):
    p = write_pipeline(tmp_path, "{n: 4, kill_always: m002}")
    r = run(p, tmp_path, "o", use_cache=False, executor=dask_local)
    assert r.status["src"] == "partial" and ("src", "m002") in r.item_errors
    assert "Dask cluster lost it" in r.item_errors[("src", "m002")]
    assert "m000" in r.outputs("report", "report")["items"]


def test_a_cluster_reached_by_address_checks_it_sees_our_files(tmp_path, dask_local):
    remote = DaskExecutor(dask_local.cluster.scheduler_address)  # as a user's --dask tcp://...
    try:
        assert remote.cluster is None
        p = write_pipeline(tmp_path, "{n: 3}")
        r = run(p, tmp_path, "o", cache_dir=tmp_path / "cache", executor=remote)
    finally:
        remote.close()
    assert r.ok and r.reports["src"].items_ran == 3
    assert not list(tmp_path.rglob(".stereograph-probe-*"))  # the probes are cleaned up


def test_a_cluster_that_does_not_see_our_files_is_refused_before_anything_runs(tmp_path):
    # A cluster whose workers lack the shared storage cannot be made on one machine, so the
    # workers' answer is given here: every worker reports that it cannot read the probe file.
    from stereograph.core.errors import ConfigError

    class BlindClient:
        def run(self, fn, *args):
            return {"tcp://10.0.0.7:4000": False, "tcp://10.0.0.8:4000": True}

    ex = DaskExecutor.__new__(DaskExecutor)
    ex.client, ex.cluster, ex.workers = BlindClient(), None, 2
    p = write_pipeline(tmp_path, "{n: 3}")
    with pytest.raises(ConfigError) as e:
        run(p, tmp_path, "o", cache_dir=tmp_path / "cache", executor=ex)
    assert "10.0.0.7" in e.value.message and "10.0.0.8" not in e.value.message
    assert "network file system" in (e.value.hint or "")
    assert not (tmp_path / "cache" / "objects").exists()  # nothing ran, nothing was stored
    assert not list(tmp_path.rglob(".stereograph-probe-*"))


def _trim_threshold():
    import os

    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


# (a Nanny writes its workers' settings into this process's environment too)
_TRIM_BEFORE = _trim_threshold()


@pytest.mark.slow
def test_local_workers_keep_the_allocators_adaptive_threshold(dask_local):
    """Dask's default MALLOC_TRIM_THRESHOLD_ made every image a fresh mmap (8 s of kernel time per
    worker on locate.yaml): our local workers start without it, unless the environment sets it."""
    # (one may still restart after the kill tests)
    dask_local.client.wait_for_workers(2, timeout=60)
    seen = dask_local.client.run(_trim_threshold)
    assert len(seen) == 2
    assert set(seen.values()) == {_TRIM_BEFORE}
