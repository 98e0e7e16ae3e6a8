"""Issue 13: one cache per project, images stored once as PNG, manifest-only entries recomputed
when needed, reruns that load nothing they do not need, an LRU budget."""

from __future__ import annotations

import json
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

from stereograph.core import cache as cache_mod
from stereograph.core import project
from stereograph.core.cache import ArtifactStore
from stereograph.core.errors import ConfigError
from stereograph.core.runner import run_pipeline

PLUGIN = """\
import numpy as np
from stereograph.core.api import Field, In, Out, Params, node

class NoiseParams(Params):
    n: int = Field(3, ge=1, description="How many images (count).")

@node("disk.noise", outputs={"images": Out("Image", collection=True)}, params=NoiseParams)
def noise(params):
    rng = np.random.default_rng(0)
    return {"images": {f"i{k}": rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
                       for k in range(params.n)}}

@node("disk.flip", inputs={"image": In("Image")}, outputs={"flipped": Out("Image")})
def flip(params, image):
    return {"flipped": image[::-1].copy()}

class MeanParams(Params):
    scale: float = Field(1.0, description="Multiplier (unitless).")

@node("disk.mean", inputs={"image": In("Image")}, outputs={"mean": Out("Number")},
      params=MeanParams)
def mean(params, image):
    return {"mean": params.scale * float(image[:10].mean())}

@node("disk.sum", inputs={"values": In("Number", gather=True)}, outputs={"total": Out("Number")})
def total(params, values):
    return {"total": float(sum(values[k] for k in sorted(values)))}
"""


def pipeline(
    folder: Path,
    name: str = "p",
    scale: float = 1.0,
    shown: str = "",
    plugin_dir: Path | None = None,
) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    plugin = (plugin_dir or folder.parent) / "diskplug.py"
    plugin.write_text(PLUGIN)
    p = folder / f"{name}.yaml"
    p.write_text(
        textwrap.dedent(f"""\
        name: {name}
        plugins: [{plugin}]
        nodes:
          src: {{type: disk.noise}}
          flip: {{type: disk.flip, inputs: {{image: src.images}}}}
          mean: {{type: disk.mean, params: {{scale: {scale}}}, inputs: {{image: flip.flipped}}}}
          total: {{type: disk.sum, inputs: {{values: mean.mean}}}}
        {shown}""")
    )
    return p


@pytest.fixture(autouse=True)
def _no_env(monkeypatch):
    monkeypatch.delenv("STEREOGRAPH_CACHE_DIR", raising=False)
    monkeypatch.delenv("STEREOGRAPH_CACHE_BUDGET_GB", raising=False)


def test_pipelines_of_one_project_share_its_cache_and_runs(tmp_path, monkeypatch):
    proj = tmp_path / "proj"
    proj.mkdir()
    (proj / "pyproject.toml").write_text("[project]\nname = 'x'\n")
    # (the project's one plugin file, used by both: two copies of it in two folders are two modules,
    # whose code keys differ by their paths)
    a = pipeline(proj / "a" / "deep", "one", plugin_dir=proj)
    b = pipeline(proj / "b", "two", plugin_dir=proj)
    r1 = run_pipeline(a)
    assert r1.ok and r1.out_dir.parent.parent == proj / "runs"
    assert (proj / ".stereograph" / "cache" / "objects").is_dir()
    r2 = run_pipeline(b)  # another folder of the same project: everything already there
    assert r2.ok and set(r2.status.values()) == {"cached"}
    assert r2.outputs("total", "total") == r1.outputs("total", "total")
    monkeypatch.setenv("STEREOGRAPH_CACHE_DIR", str(tmp_path / "elsewhere"))
    assert project.cache_dir(proj / "b") == tmp_path / "elsewhere"
    r3 = run_pipeline(b)
    assert r3.ok and r3.status["src"] == "ran" and (tmp_path / "elsewhere" / "objects").is_dir()


def test_outside_a_project_the_pipeline_folder_is_the_root(tmp_path):
    assert project.project_root(tmp_path / "p.yaml") == tmp_path
    assert project.runs_dir(tmp_path) == tmp_path / "runs"


def test_images_are_stored_once_as_png_and_linked_into_the_run_folder(tmp_path):
    p = pipeline(tmp_path / "x", shown="")
    r = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o")
    assert r.ok
    pngs = list((tmp_path / "c" / "objects").rglob("*.png"))
    assert len(pngs) >= 3 and not list((tmp_path / "c" / "objects").rglob("arrays.npz"))
    first = json.loads(next((tmp_path / "c" / "objects").rglob("manifest.json")).read_text())
    assert first["format"] == cache_mod.FORMAT
    # a saved image output lands in the run folder as the entry's own file (one inode, no rendered/
    # copy)
    store = ArtifactStore(tmp_path / "c")
    img = np.random.default_rng(1).integers(0, 256, (40, 50), dtype=np.uint8)
    store.save("k" * 32, {"picture": img})
    assert np.array_equal(store.load("k" * 32)["picture"], img)
    ready = store.ready_file("k" * 32, "picture")
    assert ready is not None and ready.suffix == ".png"


def test_an_entry_of_another_cache_format_is_computed_again(tmp_path):
    """A cache written by an older stereograph (another entry layout) is never read with this
    layout's rules: its entries count as absent, are computed again and stored anew."""
    p = pipeline(tmp_path / "x")
    first = run_pipeline(p, cache_dir=tmp_path / "c")
    manifests = list((tmp_path / "c" / "objects").rglob("manifest.json"))
    for f in manifests:
        man = json.loads(f.read_text())
        f.write_text(json.dumps({**man, "format": "1"}))
    again = run_pipeline(p, cache_dir=tmp_path / "c")
    assert again.ok and set(again.status.values()) == {"ran"}
    assert again.outputs("total", "total") == first.outputs("total", "total")
    assert {json.loads(f.read_text())["format"] for f in manifests} == {cache_mod.FORMAT}
    assert set(run_pipeline(p, cache_dir=tmp_path / "c").status.values()) == {"cached"}


def test_toy_saved_images_share_their_inode_with_the_cache(tmp_path):
    toy = Path(__file__).parent / "plugins" / "toy.py"
    p = tmp_path / "t.yaml"
    p.write_text(
        f"name: t\nplugins: [{toy}]\nnodes:\n  numbers: {{type: toy.numbers, params: {{n: "
        "2, size: 20}}\n"
        "  picture: {type: toy.picture, inputs: {m: numbers.items}}\n"
    )
    assert run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o").ok
    out = sorted((tmp_path / "o" / "picture" / "picture").glob("*.png"))
    cached = {f.stat().st_ino for f in (tmp_path / "c" / "objects").rglob("*.png")}
    assert len(out) == 2 and all(f.stat().st_ino in cached for f in out)
    assert not (tmp_path / "c" / "rendered").exists()


def test_manifest_only_entries_are_recomputed_when_a_node_needs_them(tmp_path, monkeypatch):
    real_save = ArtifactStore.save

    def always_cheaper(self, key, outputs, meta=None, compute_seconds=None):
        # as if every node were cheaper to recompute than its images are to decode
        return real_save(self, key, outputs, meta, 0.0 if compute_seconds is not None else None)

    monkeypatch.setattr(ArtifactStore, "save", always_cheaper)
    p = pipeline(tmp_path / "x")
    r1 = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o1")
    assert r1.ok
    mans = [json.loads(f.read_text()) for f in (tmp_path / "c" / "objects").rglob("manifest.json")]
    only = [m for m in mans if m.get("recompute")]
    assert {m["meta"]["node"] for m in only} == {"flip"} and all(not m["files"] for m in only)
    r2 = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o2")
    assert set(r2.status.values()) == {"cached"}
    p3 = pipeline(tmp_path / "x", scale=2.0)  # mean must run, so flip's values are computed again
    r3 = run_pipeline(p3, cache_dir=tmp_path / "c", out_dir=tmp_path / "o3")
    fresh = run_pipeline(p3, use_cache=False, out_dir=tmp_path / "o4")
    assert r3.ok and r3.status["flip"] == "cached" and r3.status["mean"] == "ran"
    assert r3.outputs("total", "total") == fresh.outputs("total", "total")


def test_a_rerun_with_nothing_changed_loads_nothing(tmp_path, monkeypatch):
    p = pipeline(tmp_path / "x")
    assert run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o1").ok
    loaded = []
    real_load = ArtifactStore.load
    monkeypatch.setattr(
        ArtifactStore, "load", lambda self, key: loaded.append(key) or real_load(self, key)
    )
    r = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o2")
    assert r.ok and set(r.status.values()) == {"cached"}
    # items from the manifests' indexes, the terminal JSON from its rendered copy
    assert loaded == []
    assert (tmp_path / "o2" / "total" / "total.json").exists()
    assert r.outputs("total", "total") is not None and len(loaded) == 1  # asked for: loaded then


def test_the_cache_stays_within_its_budget(tmp_path, monkeypatch):
    p = pipeline(tmp_path / "x", "one")
    monkeypatch.setenv("STEREOGRAPH_CACHE_BUDGET_GB", "0.00003")  # 30 kB: less than the images
    r = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o1")
    assert r.ok and any("budget" in n for n in r.notes)
    assert ArtifactStore(tmp_path / "c").info()["bytes"] <= 30_000
    # pruned: computed again
    r2 = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o2")
    assert r2.ok and r2.outputs("total", "total") == r.outputs("total", "total")
    monkeypatch.setenv("STEREOGRAPH_CACHE_BUDGET_GB", "lots")
    with pytest.raises(ConfigError, match="STEREOGRAPH_CACHE_BUDGET_GB"):
        run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o3")


def test_cache_info_names_a_budget_that_is_not_a_number(tmp_path, monkeypatch, capsys):
    from stereograph.app.cli import main

    monkeypatch.setenv("STEREOGRAPH_CACHE_BUDGET_GB", "-1")
    assert main(["cache", "info", "--cache-dir", str(tmp_path / "c")]) == 2
    said = " ".join(capsys.readouterr().err.split())
    assert "cache budget: STEREOGRAPH_CACHE_BUDGET_GB = '-1' must be 0 (no limit) or more" in said
    assert "Fix: set it in GB" in said


def test_entry_points_come_from_an_index_renewed_when_packages_change(tmp_path, monkeypatch):
    from stereograph.core import registry

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    registry._all_groups.cache_clear()
    assert "rectifier.remap" in registry.names()
    index = registry.index_file()
    assert index.is_file() and str(tmp_path) in str(index)
    # the index is what is read while sys.path's folders are unchanged ...
    index.write_text(
        json.dumps(
            [
                {
                    "fingerprint": registry._fingerprint(),
                    "groups": {registry.GROUP: {"only.this": "x:y"}},
                }
            ]
        )
    )
    registry._all_groups.cache_clear()
    assert registry.names() == ["only.this"] or "only.this" in registry.names()
    # ... and a changed folder (a package installed) makes it scan again
    index.write_text(
        json.dumps(
            [{"fingerprint": [["/nowhere", 1]], "groups": {registry.GROUP: {"only.this": "x:y"}}}]
        )
    )
    registry._all_groups.cache_clear()
    assert "only.this" not in registry.names() and "rectifier.remap" in registry.names()
    registry._all_groups.cache_clear()


def _left_by_a_killed_run(store: ArtifactStore, age_s: float, size: int = 50_000) -> Path:
    """A tmp/ folder as a run killed while writing an entry leaves it, last touched ``age_s``
    ago."""
    import os
    import time
    import uuid

    d = store.tmp / uuid.uuid4().hex
    d.mkdir(parents=True)
    (d / "image.png").write_bytes(b"\0" * size)
    then = time.time() - age_s
    for p in (d / "image.png", d):
        os.utime(p, (then, then))
    return d


def test_what_killed_runs_left_in_tmp_is_reported_and_pruned(tmp_path, monkeypatch, capsys):
    from stereograph.app.cli import main

    p = pipeline(tmp_path / "x", "one")
    assert run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o1").ok
    store = ArtifactStore(tmp_path / "c")
    entries = store.info()["entries"]
    old = _left_by_a_killed_run(store, 2 * cache_mod.ABANDONED_AFTER_S)
    writing = _left_by_a_killed_run(store, 1.0)  # a run writing now: not touched
    mine = store.tmp / "notes"  # not a name the store gives: not the store's to remove
    mine.mkdir()
    info = store.info()
    assert (info["abandoned"], info["abandoned_bytes"], info["entries"]) == (1, 50_000, entries)
    assert main(["cache", "info", "--cache-dir", str(tmp_path / "c")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "1 unfinished entry killed runs left" in said
    assert re.search(r"disk\.sum 1 entry \d", said)  # (one total: one entry)
    assert main(["cache", "prune", "--max-gb", "100", "--cache-dir", str(tmp_path / "c")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert (
        "removed 0 least recently used entries (0.0 MB)" in said
        and "removed 0.1 MB of unfinished" in said
    )
    assert not old.exists() and writing.exists() and mine.exists()
    assert store.info()["entries"] == entries

    # a run that stores something under a budget sweeps them too
    old = _left_by_a_killed_run(store, 2 * cache_mod.ABANDONED_AFTER_S)
    monkeypatch.setenv("STEREOGRAPH_CACHE_BUDGET_GB", "5")
    assert run_pipeline(
        pipeline(tmp_path / "x", "one", scale=2.0),
        cache_dir=tmp_path / "c",
        out_dir=tmp_path / "o2",
    ).ok
    assert not old.exists() and writing.exists()
